#include "testlib.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <random>
#include <sstream>
#include <stdexcept>
#include <thread>

#include <lcm/lcm-cpp.hpp>

#include "tipforce/forward.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/reference.hpp"

namespace tfdtest {

std::string test_config(int queue_capacity, double stats_period_s, int modes, const std::string& extra_daemon) {
  std::ostringstream s;
  s << "[daemon]\n"
    << "queue_capacity = " << queue_capacity << "\n"
    << "stats_period_s = " << stats_period_s << "\n"
    << "backend = \"cpu\"\n"
    << extra_daemon << "\n"
    << "[probe.tip]\n"
       "length_m = 525e-6\n"
       "width_m = 35e-6\n"
       "thickness_m = 5e-6\n"
       "youngs_modulus_pa = 1.76e11\n"
       "density_kg_m3 = 2330\n"
       "quality_factor = 100\n"
    << "modes = " << modes << "\n"
    << "model = \"spring\"\n"
       "unknowns = { k_n_per_m = [0.1, 20.0], h_m = [0.0, 60e-9] }\n"
       "[probe.tip.inversion]\n"
       "swarm_size = 24\n"
       "max_generations = 25\n"
       "warm_swarm_size = 12\n"
       "warm_max_generations = 6\n"
       "lm_max_iterations = 15\n";
  return s.str();
}

void write_log(const fs::path& path, const std::vector<Event>& events) {
  lcm::LogFile log(path.string(), "w");
  if (!log.good()) throw std::runtime_error("cannot write " + path.string());
  for (const Event& e : events) {
    lcm::LogEvent le{};
    le.eventnum = 0;
    le.timestamp = e.timestamp;
    le.channel = e.channel;
    le.datalen = static_cast<int32_t>(e.data.size());
    le.data = const_cast<std::uint8_t*>(e.data.data());
    log.writeEvent(&le);
  }
}

std::vector<Event> read_log(const fs::path& path) {
  std::vector<Event> out;
  if (!fs::exists(path)) return out;
  lcm::LogFile log(path.string(), "r");
  if (!log.good()) return out;
  while (const lcm::LogEvent* e = log.readNextEvent()) {
    Event ev;
    ev.channel = e->channel;
    ev.timestamp = e->timestamp;
    const auto* p = static_cast<const std::uint8_t*>(e->data);
    ev.data.assign(p, p + e->datalen);
    out.push_back(std::move(ev));
  }
  return out;
}

std::vector<Event> make_scan(const tipforce::Config& config, const ScanOptions& o, std::vector<TruthRow>* truth) {
  using namespace tipforce;
  const ProbeModel pm = config.probe_model(o.probe);
  const ModalModel& modal = pm.modal;
  const ParameterSpace& space = pm.space;
  auto backend = make_cpu_backend(1);
  const double f1 = modal.modes()[0].frequency_hz;
  const bool domains = o.pattern == ScanOptions::Pattern::domains;
  const double dt = domains ? 1e-6 : 1.0 / (f1 * o.samples_per_period);

  Window w;
  w.sample_period_s = dt;
  w.drive.kind = DriveKind::sine;
  // domains: tipforce bench's 1 MHz line (cmd_bench.cpp): 2 nm at 25.6 kHz, h 20-26 nm.
  w.drive.amplitude_m = domains ? 2e-9 : o.drive_amplitude_m;
  w.drive.frequency_hz = domains ? 25600.0 : f1;
  w.drive.phase_rad = 0;
  w.deflection_m.assign(static_cast<std::size_t>(o.samples), 0.0);

  const std::vector<std::string> names = space.unknown_names();
  auto full_for = [&](double k, double h) {
    std::vector<double> unknowns;
    for (const auto& n : names) {
      if (n == "k_n_per_m") unknowns.push_back(k);
      else if (n == "h_m") unknowns.push_back(h);
      else unknowns.push_back(0.5 * (space.lower()[unknowns.size()] + space.upper()[unknowns.size()]));
    }
    std::vector<double> full(static_cast<std::size_t>(space.n_full()));
    space.assemble(w, unknowns.data(), full.data());
    return full;
  };

  // Free amplitude of the tip (surface far away), to place the surface inside the oscillation.
  ModalState state = linear_steady_state(modal, w.drive.amplitude_m, w.drive.frequency_hz, 0.0, 0.0);
  w.t0_s = 0;
  double free_amp = 0;
  {
    auto full = full_for(1.0, 1.0);
    ForwardOutput free = simulate_one(*backend, modal, space.model(), w, full, state);
    for (double z : free.tip_z_m) free_amp = std::max(free_amp, z);
  }

  std::mt19937_64 rng(o.seed);
  std::normal_distribution<double> noise(0.0, o.noise_m);
  std::vector<Event> events;
  const std::int64_t t_start = 1'700'000'000'000'000;
  for (int i = 0; i < o.windows; ++i) {
    const int x = i % o.width, y = i / o.width;
    const double k = domains ? ((x + 8 * y) / 16 % 2 == 0 ? 1.0 : 4.0)
                             : 1.0 + 3.0 * (0.5 + 0.5 * std::sin(0.7 * x + 0.3 * y));
    const double h = domains ? 20e-9 + 2e-9 * (x / 24 % 4)
                             : free_amp * (0.55 + 0.3 * (0.5 + 0.5 * std::cos(0.5 * x + 0.9 * y)));
    w.t0_s = i * o.samples * dt;
    w.initial = i == 0 || (o.line_starts_unknown && x == 0) ? InitialState::unknown : InitialState::continued;
    auto full = full_for(k, h);
    if (o.false_continuation_every > 0 && i > 0 && i % o.false_continuation_every == 0)
      state = linear_steady_state(modal, w.drive.amplitude_m, w.drive.frequency_hz, 0.0, w.t0_s);
    ForwardOutput out = simulate_one(*backend, modal, space.model(), w, full, state);
    state = out.end_state.at(0);
    Window measured = w;
    for (int n = 0; n < o.samples; ++n)
      measured.deflection_m[static_cast<std::size_t>(n)] = out.signal[static_cast<std::size_t>(n)] + noise(rng);
    lcmio::WindowHeader hd;
    hd.utime = t_start + static_cast<std::int64_t>(i * o.spacing_s * 1e6);
    hd.probe = o.probe;
    hd.seq = i;
    hd.pixel_x = x;
    hd.pixel_y = y;
    deflection_window_t msg = lcmio::to_message(hd, measured);
    events.push_back(Event{o.channel, hd.utime, encode(msg)});
    if (truth) {
      TruthRow row;
      row.seq = i;
      row.pixel_x = x;
      row.pixel_y = y;
      row.values["k_n_per_m"] = k;
      row.values["h_m"] = h;
      truth->push_back(row);
    }
  }
  return events;
}

void write_truth_csv(const fs::path& path, const std::vector<TruthRow>& truth) {
  std::ofstream f(path);
  f << "seq,pixel_x,pixel_y";
  if (!truth.empty())
    for (const auto& [name, v] : truth.front().values) f << "," << name;
  f << "\n";
  f.precision(12);
  for (const auto& r : truth) {
    f << r.seq << "," << r.pixel_x << "," << r.pixel_y;
    for (const auto& [name, v] : r.values) f << "," << v;
    f << "\n";
  }
}

tipforce::deflection_window_t small_window(const std::string& probe, std::int64_t seq, int samples) {
  tipforce::deflection_window_t m{};
  m.utime = 1'700'000'000'000'000 + seq;
  m.probe = probe;
  m.seq = seq;
  m.pixel_x = static_cast<int32_t>(seq);
  m.pixel_y = 0;
  m.initial_state = tipforce::deflection_window_t::INITIAL_REST;
  m.t0_s = 0;
  m.sample_period_s = 1.0 / (25468.9 * 50);
  m.drive_kind = tipforce::deflection_window_t::DRIVE_SINE;
  m.drive_amplitude_m = 0.1e-9;
  m.drive_frequency_hz = 25468.9;
  m.n_samples = samples;
  m.deflection_m.resize(static_cast<std::size_t>(samples));
  for (int n = 0; n < samples; ++n)
    m.deflection_m[static_cast<std::size_t>(n)] = static_cast<float>(1e-9 * std::sin(2 * M_PI * n / 50.0) * n / samples);
  m.n_base_samples = 0;
  return m;
}

std::optional<int> Child::wait(std::chrono::milliseconds timeout) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    int status = 0;
    const pid_t r = ::waitpid(pid, &status, WNOHANG);
    if (r == pid) {
      pid = -1;
      if (WIFEXITED(status)) return WEXITSTATUS(status);
      if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
      return -1;
    }
    if (r < 0) return -1;
    if (std::chrono::steady_clock::now() >= end) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

void Child::signal(int signo) const {
  if (pid > 0) ::kill(pid, signo);
}

void Child::kill_and_reap() {
  if (pid <= 0) return;
  ::kill(pid, SIGKILL);
  int status = 0;
  ::waitpid(pid, &status, 0);
  pid = -1;
}

Child spawn(const std::vector<std::string>& argv, const fs::path& log, const std::map<std::string, std::string>& env) {
  Child c;
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  c.pid = ::fork();
  if (c.pid < 0) throw std::runtime_error("fork failed");
  if (c.pid == 0) {
    if (!log.empty()) {
      const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (fd >= 0) {
        ::dup2(fd, 1);
        ::dup2(fd, 2);
        ::close(fd);
      }
    }
    for (const auto& [k, v] : env) ::setenv(k.c_str(), v.c_str(), 1);
    ::execvp(args[0], args.data());
    std::perror("execvp");
    ::_exit(127);
  }
  return c;
}

NotifyListener::NotifyListener(fs::path path) : path_(std::move(path)) {
  ::unlink(path_.c_str());
  fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  sockaddr_un a{};
  a.sun_family = AF_UNIX;
  std::snprintf(a.sun_path, sizeof(a.sun_path), "%s", path_.c_str());
  if (fd_ < 0 || ::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0)
    throw std::runtime_error("cannot bind " + path_.string());
}

NotifyListener::~NotifyListener() {
  if (fd_ >= 0) ::close(fd_);
  ::unlink(path_.c_str());
}

std::string NotifyListener::receive(std::chrono::milliseconds timeout) {
  pollfd p{fd_, POLLIN, 0};
  if (::poll(&p, 1, static_cast<int>(timeout.count())) <= 0) return {};
  char buf[1024];
  const ssize_t n = ::recv(fd_, buf, sizeof(buf), 0);
  return n > 0 ? std::string(buf, static_cast<std::size_t>(n)) : std::string();
}

bool LiveProcess::start(const std::string& tipforced, const fs::path& dir, const fs::path& config,
                        const std::string& input_url, const std::string& output_url,
                        const std::map<std::string, std::string>& extra_env, const std::vector<std::string>& extra_args,
                        const std::vector<std::string>& prefix) {
  notify = std::make_unique<NotifyListener>(dir / "notify.sock");
  stderr_path = dir / "stderr.txt";
  auto env = extra_env;
  env["NOTIFY_SOCKET"] = notify->path().string();
  std::vector<std::string> argv = prefix;
  for (const std::string& a : {tipforced, std::string("--config"), config.string(), std::string("--input-url"), input_url})
    argv.push_back(a);
  if (!output_url.empty()) {
    argv.push_back("--output-url");
    argv.push_back(output_url);
  }
  argv.insert(argv.end(), extra_args.begin(), extra_args.end());
  child = spawn(argv, stderr_path, env);
  for (;;) {
    std::string m = notify->receive(std::chrono::seconds(60));
    if (m.empty()) return false;
    notifications.push_back(m);
    if (m.rfind("READY=1", 0) == 0) break;
  }
  // From here on read as systemd does, all along: a socket nobody reads fills after 10 datagrams
  // (net.unix.max_dgram_qlen), and the watchdog pings would then be lost.
  reading_ = true;
  reader_ = std::thread([this] {
    while (reading_) {
      std::string m = notify->receive(std::chrono::milliseconds(50));
      if (m.empty()) continue;
      std::lock_guard<std::mutex> lock(mutex_);
      notifications.push_back(std::move(m));
    }
  });
  return true;
}

void LiveProcess::stop_reading() {
  if (!reader_.joinable()) return;
  reading_ = false;
  reader_.join();
  for (std::string m; !(m = notify->receive(std::chrono::milliseconds(50))).empty();) notifications.push_back(m);
}

std::pair<std::optional<int>, double> LiveProcess::stop() {
  const auto t0 = std::chrono::steady_clock::now();
  child.signal(SIGTERM);
  auto code = child.wait(std::chrono::seconds(10));
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!code) child.kill_and_reap();
  stop_reading();
  return {code, took};
}

LiveProcess::~LiveProcess() {
  child.kill_and_reap();
  stop_reading();
}

std::string read_text(const fs::path& path) {
  std::ifstream f(path);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

void write_text(const fs::path& path, const std::string& text) {
  std::ofstream f(path);
  f << text;
}

}  // namespace tfdtest
