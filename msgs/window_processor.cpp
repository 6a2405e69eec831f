#include "tipforce/window_processor.hpp"

#include <chrono>
#include <exception>

namespace tipforce::lcmio {

WindowProcessor::WindowProcessor(const Config& config, ForwardBackend& backend) {
  for (const auto& [name, probe] : config.probes) {
    (void)probe;
    inverters_.emplace(name, std::make_unique<Inverter>(config.probe_model(name), backend));
  }
}

ProcessedWindow WindowProcessor::process(const void* data, std::size_t size, int64_t receive_utime) {
  ProcessedWindow out;
  DecodedWindow decoded = decode_window(data, size);
  if (!decoded.attributable) {
    out.rejected = true;
    out.reason = decoded.error;
    return out;
  }
  auto it = inverters_.find(decoded.header.probe);
  std::string model = it == inverters_.end() ? "" : std::string(to_string(it->second->probe().space.model()));
  if (decoded.error.empty() && it == inverters_.end())
    decoded.error = "unknown probe '" + decoded.header.probe + "' (not in the config)";
  if (!decoded.error.empty()) {
    out.rejected = true;
    out.reason = decoded.error;
    out.estimate = rejected_estimate(decoded.header, model, decoded.error, receive_utime, now_utime());
    return out;
  }
  Inverter& inverter = *it->second;
  // A window that claims to continue the previous one but does not follow it directly (a gap in
  // seq: windows dropped or lost) starts where the last fit, coasted across the gap with its
  // estimate, says the cantilever is; with nothing to coast from, its start is unknown.
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
  out.rejected = estimate.status == EstimateStatus::rejected;
  if (out.rejected) out.reason = estimate.message;
  out.estimate = to_message(decoded.header, model, estimate, receive_utime, now_utime());
  return out;
}

}  // namespace tipforce::lcmio
