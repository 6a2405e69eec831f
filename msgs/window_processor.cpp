#include "tipforce/window_processor.hpp"

#include <chrono>
#include <exception>
#include <variant>

namespace tipforce::lcmio {

WindowProcessor::WindowProcessor(const Config& config, ForwardBackend& backend) {
  for (const auto& [name, probe] : config.probes) {
    Probe p;
    p.inverter = std::make_unique<Inverter>(config.probe_model(name), backend);
    const auto* beam = std::get_if<BeamGeometry>(&probe.spec.cantilever);
    p.limits = window_limits(p.inverter->probe().modal, beam != nullptr ? beam->length_m : 0.0, probe.space,
                             config.daemon.max_window_samples);
    if (probe.advisor) {
      p.advisor.emplace(p.inverter->probe().modal, probe.space, *probe.advisor);
      p.advisor_options = *probe.advisor;
    }
    probes_.emplace(name, std::move(p));
  }
}

ProcessedWindow WindowProcessor::process(const void* data, std::size_t size, int64_t receive_utime) {
  ProcessedWindow out;
  last_.reset();
  DecodedWindow decoded = decode_window(data, size);
  if (!decoded.attributable) {
    out.rejected = true;
    out.reason = decoded.error;
    return out;
  }
  auto it = probes_.find(decoded.header.probe);
  std::string model =
      it == probes_.end() ? "" : std::string(to_string(it->second.inverter->probe().space.model()));
  if (decoded.error.empty() && it == probes_.end())
    decoded.error = "unknown probe '" + decoded.header.probe + "' (not in the config)";
  if (decoded.error.empty()) {
    if (auto problem = window_problem_for_probe(decoded.window, it->second.limits)) decoded.error = *problem;
  }
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
  Inverter& inverter = *it->second.inverter;
  // A window that claims to continue the previous one but does not follow it directly (a gap in
  // seq: windows dropped, lost or rejected) starts where the last fit, coasted across the gap with
  // its estimate, says the cantilever is; with nothing to coast from, its start is unknown.
  auto last = last_seq_.find(decoded.header.probe);
  if (decoded.window.initial == InitialState::continued &&
      (last == last_seq_.end() || last->second + 1 != decoded.header.seq) &&
      (last == last_seq_.end() || decoded.header.seq <= last->second ||
       !inverter.coast_to(decoded.window.t0_s, decoded.window.sample_period_s))) {
    decoded.window.initial = InitialState::unknown;
  }
  last_seq_[decoded.header.probe] = decoded.header.seq;
  const auto t0 = std::chrono::steady_clock::now();
  Estimate estimate;
  try {
    estimate = inverter.invert(decoded.window);
  } catch (const std::exception& e) {
    // The inverter answers bad data with a status; an exception here is a bug, but the service
    // keeps answering.
    estimate = Estimate{};
    estimate.status = EstimateStatus::rejected;
    estimate.message = std::string("internal error: ") + e.what();
  }
  out.solve_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
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
