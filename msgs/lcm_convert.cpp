#include "tipforce/lcm_convert.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>

namespace tipforce::lcmio {
namespace {

// Reads a deflection_window_t's wire format (big-endian, after the 8-byte fingerprint) far enough
// to name the window and to check the declared array lengths against the bytes that are there, so
// that a broken window can still be answered and a lying n_samples never sizes an allocation.
class WireReader {
 public:
  WireReader(const uint8_t* p, std::size_t n) : p_(p), n_(n) {}
  bool skip(std::size_t k) {
    if (pos_ + k > n_) return false;
    pos_ += k;
    return true;
  }
  bool i64(int64_t& out) { return big_endian(out); }
  bool i32(int32_t& out) { return big_endian(out); }
  bool str(std::string& out) {
    int32_t len = 0;
    if (!i32(len) || len <= 0 || static_cast<std::size_t>(len) > n_ - pos_ || p_[pos_ + len - 1] != 0) return false;
    out.assign(reinterpret_cast<const char*>(p_ + pos_), static_cast<std::size_t>(len - 1));
    pos_ += static_cast<std::size_t>(len);
    return true;
  }
  std::size_t remaining() const { return n_ - pos_; }

 private:
  template <typename T>
  bool big_endian(T& out) {
    if (pos_ + sizeof(T) > n_) return false;
    std::make_unsigned_t<T> v = 0;
    for (std::size_t i = 0; i < sizeof(T); ++i) v = static_cast<std::make_unsigned_t<T>>((v << 8) | p_[pos_ + i]);
    pos_ += sizeof(T);
    out = static_cast<T>(v);
    return true;
  }
  const uint8_t* p_;
  std::size_t n_;
  std::size_t pos_ = 8;
};

// Empty when the arrays' declared lengths fit the message, else why not.
std::string check_array_lengths(WireReader r) {
  // initial_state, t0_s, sample_period_s, drive_kind, four drive doubles
  if (!r.skip(1 + 8 + 8 + 1 + 4 * 8)) return "message ends inside the drive fields";
  int32_t n = 0;
  if (!r.i32(n)) return "message ends before n_samples";
  if (n < 0) return "n_samples must be positive, got " + std::to_string(n);
  if (static_cast<std::size_t>(n) * 4 > r.remaining())
    return "n_samples " + std::to_string(n) + " disagrees with the data: only " + std::to_string(r.remaining()) +
           " bytes follow";
  r.skip(static_cast<std::size_t>(n) * 4);
  int32_t nb = 0;
  if (!r.i32(nb)) return "message ends before n_base_samples";
  if (nb < 0 || static_cast<std::size_t>(nb) * 4 != r.remaining())
    return "n_base_samples " + std::to_string(nb) + " disagrees with the data: " + std::to_string(r.remaining()) +
           " bytes follow";
  return {};
}

bool read_header(WireReader& r, WindowHeader& h) {
  return r.i64(h.utime) && r.str(h.probe) && r.i64(h.seq) && r.i32(h.pixel_x) && r.i32(h.pixel_y);
}

bool fingerprint_is(const void* data, std::size_t size, int64_t fingerprint) {
  int64_t hash = 0;
  return data != nullptr && size >= 8 && size <= static_cast<std::size_t>(INT32_MAX) &&
         __int64_t_decode_array(data, 0, static_cast<int>(size), &hash, 1) == 8 && hash == fingerprint;
}
bool window_fingerprint(const void* data, std::size_t size) {
  return fingerprint_is(data, size, deflection_window_t::getHash());
}

// deflection_window_t and force_estimate_t begin with the same five fields.
std::optional<WindowHeader> decode_header(const void* data, std::size_t size, int64_t fingerprint) {
  if (!fingerprint_is(data, size, fingerprint)) return std::nullopt;
  WireReader reader(static_cast<const uint8_t*>(data), size);
  WindowHeader h;
  if (!read_header(reader, h)) return std::nullopt;
  if (probe_name_problem(h.probe)) h.probe = escape_for_log(h.probe);
  return h;
}

}  // namespace

std::optional<WindowHeader> decode_window_header(const void* data, std::size_t size) {
  return decode_header(data, size, deflection_window_t::getHash());
}

std::optional<WindowHeader> decode_estimate_header(const void* data, std::size_t size) {
  return decode_header(data, size, force_estimate_t::getHash());
}

int window_shard(const void* data, std::size_t size, const ShardSpec& spec) {
  if (!spec.sharded()) return 0;
  const auto h = decode_window_header(data, size);
  return h ? spec.shard_of(h->probe, h->pixel_y) : 0;
}

std::optional<std::string> probe_name_problem(std::string_view name) {
  if (name.empty()) return std::string("probe name is empty");
  if (name.size() > kMaxProbeNameBytes)
    return "probe name is " + std::to_string(name.size()) + " bytes, more than " + std::to_string(kMaxProbeNameBytes);
  for (std::size_t i = 0; i < name.size(); ++i) {
    const auto c = static_cast<unsigned char>(name[i]);
    if (c == 0) return "probe name has a NUL byte at " + std::to_string(i) + " (\"" + escape_for_log(name) + "\")";
    if (c < 0x20 || c > 0x7e)
      return "probe name has a non-printable byte at " + std::to_string(i) + " (\"" + escape_for_log(name) + "\")";
  }
  return std::nullopt;
}

std::string escape_for_log(std::string_view raw, std::size_t max_bytes) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out;
  const std::size_t n = std::min(raw.size(), max_bytes);
  for (std::size_t i = 0; i < n; ++i) {
    const auto c = static_cast<unsigned char>(raw[i]);
    if (c >= 0x20 && c <= 0x7e && c != '\\') {
      out += static_cast<char>(c);
    } else {
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    }
  }
  if (raw.size() > n) out += "...(" + std::to_string(raw.size() - n) + " more bytes)";
  return out;
}

int64_t now_utime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

DecodedWindow decode_window(const void* data, std::size_t size) {
  DecodedWindow out;
  const auto* bytes = static_cast<const uint8_t*>(data);
  if (data == nullptr || size < 8) {
    out.error = "message too short to be a deflection_window_t (" + std::to_string(size) + " bytes)";
    return out;
  }
  if (!window_fingerprint(data, size)) {
    out.error = "not a tipforce.deflection_window_t (fingerprint mismatch)";
    return out;
  }
  // Past the fingerprint the header is readable even if the arrays are not.
  WireReader reader(bytes, size);
  WindowHeader& h = out.header;
  out.attributable = read_header(reader, h);
  if (!out.attributable) {
    out.error = "undecodable deflection_window_t header";
    return out;
  }
  if (auto why = probe_name_problem(h.probe)) {
    out.error = *why;
    h.probe = escape_for_log(h.probe);
    return out;
  }
  if (std::string why = check_array_lengths(reader); !why.empty()) {
    out.error = why;
    return out;
  }
  deflection_window_t msg;
  if (msg.decode(data, 0, static_cast<int>(size)) < 0) {
    out.error = "undecodable deflection_window_t (" + std::to_string(size) + " bytes)";
    return out;
  }
  if (msg.n_samples <= 0) {
    out.error = "n_samples must be positive, got " + std::to_string(msg.n_samples);
    return out;
  }
  Window& w = out.window;
  switch (msg.initial_state) {
    case deflection_window_t::INITIAL_REST: w.initial = InitialState::rest; break;
    case deflection_window_t::INITIAL_CONTINUED: w.initial = InitialState::continued; break;
    case deflection_window_t::INITIAL_UNKNOWN: w.initial = InitialState::unknown; break;
    default: out.error = "unknown initial_state " + std::to_string(msg.initial_state); return out;
  }
  switch (msg.drive_kind) {
    case deflection_window_t::DRIVE_SINE: w.drive.kind = DriveKind::sine; break;
    case deflection_window_t::DRIVE_CHIRP: w.drive.kind = DriveKind::chirp; break;
    case deflection_window_t::DRIVE_SAMPLED: w.drive.kind = DriveKind::sampled; break;
    default: out.error = "unknown drive_kind " + std::to_string(msg.drive_kind); return out;
  }
  w.t0_s = msg.t0_s;
  w.sample_period_s = msg.sample_period_s;
  w.drive.amplitude_m = msg.drive_amplitude_m;
  w.drive.frequency_hz = msg.drive_frequency_hz;
  w.drive.phase_rad = msg.drive_phase_rad;
  w.drive.chirp_hz_per_s = msg.drive_chirp_hz_per_s;
  if (msg.n_samples > kMaxWindowSamples) {
    out.error = "n_samples " + std::to_string(msg.n_samples) + " exceeds the limit of " +
                std::to_string(kMaxWindowSamples);
    return out;
  }
  w.deflection_m.assign(msg.deflection_m.begin(), msg.deflection_m.end());
  w.drive.base_m.assign(msg.base_m.begin(), msg.base_m.end());
  // What the samples say (finite, a positive period, ...) is the library's to judge, once: the
  // Inverter validates every window it is given (window_problem, window_problem_for_probe).
  return out;
}

deflection_window_t to_message(const WindowHeader& header, const Window& window) {
  deflection_window_t m;
  m.utime = header.utime;
  m.probe = header.probe;
  m.seq = header.seq;
  m.pixel_x = header.pixel_x;
  m.pixel_y = header.pixel_y;
  m.initial_state = static_cast<int8_t>(window.initial);
  m.t0_s = window.t0_s;
  m.sample_period_s = window.sample_period_s;
  m.drive_kind = static_cast<int8_t>(window.drive.kind);
  m.drive_amplitude_m = window.drive.amplitude_m;
  m.drive_frequency_hz = window.drive.frequency_hz;
  m.drive_phase_rad = window.drive.phase_rad;
  m.drive_chirp_hz_per_s = window.drive.chirp_hz_per_s;
  m.n_samples = window.n_samples();
  m.deflection_m.assign(window.deflection_m.begin(), window.deflection_m.end());
  m.n_base_samples = static_cast<int32_t>(window.drive.base_m.size());
  m.base_m.assign(window.drive.base_m.begin(), window.drive.base_m.end());
  return m;
}

namespace {
force_estimate_t base_estimate(const WindowHeader& header, std::string_view model, int64_t receive_utime,
                               int64_t publish_utime) {
  force_estimate_t e{};
  e.utime = header.utime;
  e.probe = header.probe;
  e.seq = header.seq;
  e.pixel_x = header.pixel_x;
  e.pixel_y = header.pixel_y;
  e.model = std::string(model);
  e.n_params = 0;
  e.receive_utime = receive_utime;
  e.publish_utime = publish_utime;
  return e;
}
}  // namespace

force_estimate_t to_message(const WindowHeader& header, std::string_view model, const Estimate& est,
                            int64_t receive_utime, int64_t publish_utime) {
  force_estimate_t e = base_estimate(header, model, receive_utime, publish_utime);
  e.status = static_cast<int8_t>(est.status);
  e.message = est.message;
  e.n_params = static_cast<int32_t>(est.values.size());
  e.param_names = est.names;
  e.params = est.values;
  e.param_sigma = est.sigma;
  e.misfit = est.misfit;
  e.peak_force_n = est.peak_force_n;
  e.mean_force_n = est.mean_force_n;
  e.max_indentation_m = est.max_indentation_m;
  e.dissipated_energy_j = est.dissipated_energy_j;
  e.iterations = est.iterations;
  e.forward_solves = est.forward_solves;
  return e;
}

force_estimate_t rejected_estimate(const WindowHeader& header, std::string_view model, const std::string& why,
                                   int64_t receive_utime, int64_t publish_utime) {
  force_estimate_t e = base_estimate(header, model, receive_utime, publish_utime);
  e.status = force_estimate_t::STATUS_REJECTED;
  e.message = why;
  e.misfit = std::nan("");
  return e;
}

}  // namespace tipforce::lcmio
