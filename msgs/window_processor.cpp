#include "tipforce/window_processor.hpp"

#include <algorithm>
#include <chrono>
#include <exception>

namespace tipforce::lcmio {

WindowProcessor::WindowProcessor(const Config& config, ForwardBackend& backend) {
  for (const auto& [name, probe] : config.probes) {
    Probe p;
    p.inverter = std::make_unique<Inverter>(config.probe_model(name), backend);
    for (const double dt_s : probe.options.prepare_sample_periods_s) p.inverter->prepare(dt_s);
    if (probe.advisor) {
      p.advisor.emplace(p.inverter->probe().modal, probe.space, *probe.advisor);
      p.advisor_options = *probe.advisor;
    }
    probes_.emplace(name, std::move(p));
  }
}

ProcessedWindow WindowProcessor::process(const void* data, std::size_t size, int64_t receive_utime,
                                         std::optional<int64_t> budget_start_utime) {
  ProcessedWindow out;
  last_.reset();
  DecodedWindow decoded = decode_window(data, size);
  if (!decoded.attributable) {
    out.rejected = true;
    out.reason = decoded.error;
    return out;
  }
  auto it = probes_.find(decoded.header.probe);
  const std::string model =
      it == probes_.end() ? "" : std::string(to_string(it->second.inverter->probe().space.model()));
  if (decoded.error.empty() && it == probes_.end())
    decoded.error = "unknown probe '" + decoded.header.probe + "' (not in the config)";
  if (!decoded.error.empty()) {
    // Nothing of the probe's stream changes: the windows after this one are answered exactly as
    // if it had never arrived (issue 10: one bad window stays one bad window).
    out.rejected = true;
    out.reason = decoded.error;
    out.estimate = rejected_estimate(decoded.header, model, decoded.error, receive_utime, now_utime());
    if (it != probes_.end()) {
      Estimate rejected;
      rejected.status = EstimateStatus::rejected;
      rejected.message = decoded.error;
      remember(it->second, decoded.header, Window{}, std::move(rejected));
    }
    return out;
  }
  // The inverter validates the window against the probe (a window it rejects leaves the stream
  // as it was, too), decides from seq how the window starts (continue, coast across a gap, or
  // cold: decide_start), and times the solve.
  Estimate estimate;
  try {
    WindowContext context{decoded.header.seq};
    // The budget's start on the steady clock: as long before now as it was on the wall clock.
    if (const int64_t start_utime = budget_start_utime.value_or(receive_utime); start_utime > 0)
      context.budget_start = std::chrono::steady_clock::now() -
                             std::chrono::microseconds(std::max<int64_t>(0, now_utime() - start_utime));
    estimate = it->second.inverter->invert(decoded.window, context);
  } catch (const std::exception& e) {
    // The inverter answers bad data with a status; an exception here is a bug, but the service
    // keeps answering.
    estimate = Estimate{};
    estimate.status = EstimateStatus::rejected;
    estimate.message = std::string("internal error: ") + e.what();
  }
  out.solve_seconds = estimate.solve_seconds;
  // Every estimate that is not OK says why (SPEC 3: message, "why, when status is not OK").
  if (estimate.status != EstimateStatus::ok && estimate.message.empty())
    estimate.message = estimate.status == EstimateStatus::rejected ? "rejected by the inverter (no reason given)"
                                                                   : "not converged (no reason given)";
  out.rejected = estimate.status == EstimateStatus::rejected;
  if (out.rejected) out.reason = estimate.message;
  out.estimate = to_message(decoded.header, model, estimate, receive_utime, now_utime());
  remember(it->second, decoded.header, std::move(decoded.window), std::move(estimate));
  return out;
}

void WindowProcessor::remember(Probe& probe, const WindowHeader& header, Window window, Estimate estimate) {
  if (probe.advisor) last_ = LastAnswer{&probe, header, std::move(window), std::move(estimate)};
}

}  // namespace tipforce::lcmio
