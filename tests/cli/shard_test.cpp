// Issue 12, acceptance 3: an archive reprocessed in shards by an existing scheduler. `tipforce
// invert --shard I/N` run under GNU parallel, the shards' logs merged by `tipforce map`, gives
// the maps of one run; and the option refuses what it cannot do.
#include <gtest/gtest.h>
#include <lcm/lcm-cpp.hpp>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "tipforce/force_estimate_t.hpp"

namespace {

namespace fs = std::filesystem;

struct Outcome {
  int status;
  std::string output;  // stdout and stderr
};

Outcome shell(const std::string& cmd) {
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  std::string out;
  std::array<char, 4096> buf{};
  while (std::size_t n = fread(buf.data(), 1, buf.size(), p)) out.append(buf.data(), n);
  const int rc = pclose(p);
  return {WIFEXITED(rc) ? WEXITSTATUS(rc) : -1, out};
}

std::string tipforce_bin() { return TIPFORCE_BIN; }

std::string slurp(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// estimates.csv without the three columns that say when a run received and published a window.
std::string without_times(const std::string& csv) {
  std::stringstream in(csv), out;
  for (std::string line; std::getline(in, line);) {
    for (int i = 0; i < 3; ++i) line = line.substr(0, line.rfind(','));
    out << line << "\n";
  }
  return out.str();
}

// An estimates log's estimates by seq (one probe).
std::map<std::int64_t, tipforce::force_estimate_t> estimates_by_seq(const std::string& path) {
  std::map<std::int64_t, tipforce::force_estimate_t> out;
  lcm::LogFile in(path, "r");
  while (const lcm::LogEvent* ev = in.readNextEvent()) {
    tipforce::force_estimate_t e;
    if (e.decode(ev->data, 0, ev->datalen) > 0) out[e.seq] = e;
  }
  return out;
}

// What an estimate says about its window, but when it was received and published: "" when equal.
std::string difference(const tipforce::force_estimate_t& a, const tipforce::force_estimate_t& b) {
  auto same = [](double x, double y) { return x == y || (std::isnan(x) && std::isnan(y)); };
  if (a.status != b.status || a.message != b.message) return "status or message";
  if (a.param_names != b.param_names || a.params != b.params || a.param_sigma != b.param_sigma) return "parameters";
  if (!same(a.misfit, b.misfit) || !same(a.peak_force_n, b.peak_force_n) || !same(a.mean_force_n, b.mean_force_n) ||
      !same(a.max_indentation_m, b.max_indentation_m) || !same(a.dissipated_energy_j, b.dissipated_energy_j))
    return "derived quantities";
  if (a.iterations != b.iterations || a.forward_solves != b.forward_solves) return "iterations";
  return {};
}

// The probe's section of a config, under another name.
std::string probe(const std::string& name) {
  return "[probe." + name + R"(]
length_m = 525e-6
width_m = 35e-6
thickness_m = 5e-6
youngs_modulus_pa = 1.76e11
density_kg_m3 = 2330
quality_factor = 100
modes = 4
model = "spring"
unknowns = { k_n_per_m = [0.5, 20.0], h_m = [10e-9, 60e-9] }
[probe.)" + name + R"(.inversion]
swarm_size = 24
max_generations = 25
warm_swarm_size = 12
warm_max_generations = 6
)";
}

class ShardCli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("tipforce_shard_cli_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  std::string write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / name) << text;
    return path(name);
  }
  // A log of several probes' scans (tipforce simulate), interleaved window by window.
  // line_start: how each later line's first window is marked ("continued" or "unknown").
  std::string multi_probe_log(const std::string& config, const std::vector<std::string>& probes, int px, int py,
                              const std::string& line_start = "continued") {
    write("scan.toml", "sample_period_s = 2e-7\nsamples_per_window = 800\npixels_x = " + std::to_string(px) +
                           "\npixels_y = " + std::to_string(py) + "\nline_start = \"" + line_start + "\"" +
                           "\nstart = \"steady\"\nnoise_m = 0.05e-9\nseed = 3\n[drive]\nkind = \"sine\"\n"
                           "amplitude_m = 2e-9\nfrequency_hz = 25600.0\n[truth]\nk_n_per_m = 4.0\nh_m = 30e-9\n");
    for (const auto& p : probes) {
      const Outcome r = shell(tipforce_bin() + " simulate --config " + config + " --probe " + p + " --scan " +
                              path("scan.toml") + " --integrator fast --out " + path(p + ".lcmlog"));
      EXPECT_EQ(r.status, 0) << r.output;
    }
    lcm::LogFile out(path("all.lcmlog"), "w");
    std::vector<std::unique_ptr<lcm::LogFile>> in;
    for (const auto& p : probes) in.push_back(std::make_unique<lcm::LogFile>(path(p + ".lcmlog"), "r"));
    for (bool more = true; more;) {
      more = false;
      for (auto& f : in) {
        if (const lcm::LogEvent* ev = f->readNextEvent()) {
          lcm::LogEvent copy = *ev;
          out.writeEvent(&copy);
          more = true;
        }
      }
    }
    return path("all.lcmlog");
  }
  fs::path dir_;
};

// Every map file two `tipforce map` runs wrote, compared: identical, but for the latency plots
// (when each run happened), estimates.csv's time columns and the PDFs' creation dates.
void expect_same_maps(const fs::path& a, const fs::path& b) {
  std::set<std::string> names;
  for (const auto& e : fs::directory_iterator(a)) names.insert(e.path().filename().string());
  std::set<std::string> names_b;
  for (const auto& e : fs::directory_iterator(b)) names_b.insert(e.path().filename().string());
  EXPECT_EQ(names, names_b);
  int compared = 0;
  for (const auto& name : names) {
    if (name.rfind("latency_", 0) == 0) continue;
    // A PDF carries the time it was written (Cairo's CreationDate); its PNG twin is compared.
    if (name.size() > 4 && name.compare(name.size() - 4, 4, ".pdf") == 0) continue;
    if (name == "estimates.csv") {
      EXPECT_EQ(without_times(slurp(a / name)), without_times(slurp(b / name))) << name;
    } else {
      EXPECT_TRUE(slurp(a / name) == slurp(b / name)) << name << " differs";
    }
    ++compared;
  }
  EXPECT_GT(compared, 10);
}

}  // namespace

TEST_F(ShardCli, ShardsRunUnderGnuParallelAndMergedByMapGiveTheMapsOfOneRun) {
  if (shell("parallel --version").status != 0) GTEST_SKIP() << "GNU parallel not installed (tools/setup.sh installs it)";
  // Four probes, split between the two shards by FNV-1a 64 of their names (that neither shard is
  // left empty is checked below from the shards' own summaries).
  const std::vector<std::string> probes = {"afm1", "afm2", "afm3", "afm4"};
  std::string text;
  for (const auto& p : probes) text += probe(p);
  const std::string config = write("c.toml", text);
  const std::string log = multi_probe_log(config, probes, 4, 2);

  const Outcome one = shell(tipforce_bin() + " invert --config " + config + " --in " + log + " --out " + path("one.lcmlog"));
  ASSERT_EQ(one.status, 0) << one.output;
  // The README's recipe: one job per shard, on every core.
  const Outcome par = shell("cd " + dir_.string() + " && parallel --halt now,fail=1 " + tipforce_bin() +
                            " invert --config " + config + " --in " + log +
                            " --out shard{}.lcmlog --shard {}/2 --shard-by probe ::: 0 1");
  ASSERT_EQ(par.status, 0) << par.output;
  for (const char* summary : {"shard 0/2 by probe: ", "shard 1/2 by probe: "})
    EXPECT_NE(par.output.find(summary), std::string::npos) << par.output;
  EXPECT_EQ(par.output.find("windows 0,"), std::string::npos) << "a shard answered nothing:\n" << par.output;
  for (const auto& p : probes) {
    const Outcome a = shell(tipforce_bin() + " map --in " + path("shard0.lcmlog") + " " + path("shard1.lcmlog") +
                            " --probe " + p + " --out " + path("merged_" + p));
    ASSERT_EQ(a.status, 0) << a.output;
    EXPECT_NE(a.output.find("read 2 logs as one"), std::string::npos) << a.output;
    EXPECT_NE(a.output.find("missing pixels: none"), std::string::npos) << a.output;
    const Outcome b = shell(tipforce_bin() + " map --in " + path("one.lcmlog") + " --probe " + p + " --out " + path("one_" + p));
    ASSERT_EQ(b.status, 0) << b.output;
    expect_same_maps(path("merged_" + p), path("one_" + p));
  }
}

// Split by line, each line starting UNKNOWN (line_start = "unknown", as an acquisition marks the
// pixel after its retrace): every window is answered by exactly one shard, and as one run answers
// it, bit for bit (a cold start depends on its window alone, issue 9).
TEST_F(ShardCli, ByLineEveryWindowIsAnsweredByExactlyOneShardAsOneRunAnswersIt) {
  const std::string config = write("c.toml", probe("afm1"));
  const std::string log = multi_probe_log(config, {"afm1"}, 3, 4, "unknown");
  const Outcome one = shell(tipforce_bin() + " invert --config " + config + " --in " + log + " --out " + path("one.lcmlog"));
  ASSERT_EQ(one.status, 0) << one.output;
  const std::map<std::int64_t, tipforce::force_estimate_t> single = estimates_by_seq(path("one.lcmlog"));
  ASSERT_EQ(single.size(), 12u);
  int equal = 0;
  std::map<std::int64_t, int> answered;
  std::set<int> lines_of[3];
  for (int i = 0; i < 3; ++i) {
    const std::string out = path("line" + std::to_string(i) + ".lcmlog");
    const Outcome r = shell(tipforce_bin() + " invert --config " + config + " --in " + log + " --out " + out + " --shard " +
                            std::to_string(i) + "/3 --shard-by line");
    ASSERT_EQ(r.status, 0) << r.output;
    lcm::LogFile in(out, "r");
    while (const lcm::LogEvent* ev = in.readNextEvent()) {
      tipforce::force_estimate_t e;
      ASSERT_GT(e.decode(ev->data, 0, ev->datalen), 0);
      ++answered[e.seq];
      lines_of[i].insert(e.pixel_y);
      const auto it = single.find(e.seq);
      ASSERT_NE(it, single.end()) << "seq " << e.seq;
      const std::string d = difference(e, it->second);
      EXPECT_EQ(d, "") << "seq " << e.seq << " (line " << e.pixel_y << ", shard " << i << "): differs from one run";
      equal += d.empty();
    }
  }
  std::printf("by line: %d of 12 estimates bit-equal to one run's\n", equal);
  EXPECT_EQ(answered.size(), 12u);
  for (const auto& [seq, n] : answered) EXPECT_EQ(n, 1) << "seq " << seq;
  // Line y goes to shard y mod 3: whole lines, never split.
  for (int i = 0; i < 3; ++i)
    for (int y : lines_of[i]) EXPECT_EQ(y % 3, i) << "line " << y << " in shard " << i;
}

TEST_F(ShardCli, AnEmptyShareGivesAnEmptyLogThatMapSkips) {
  // One probe split by probe: one shard has every window, the other none, and says so.
  const std::string config = write("c.toml", probe("afm1"));
  const std::string log = multi_probe_log(config, {"afm1"}, 2, 1);
  int empty = 0;
  for (int i = 0; i < 2; ++i) {
    const Outcome r = shell(tipforce_bin() + " invert --config " + config + " --in " + log + " --out " +
                            path("p" + std::to_string(i) + ".lcmlog") + " --shard " + std::to_string(i) +
                            "/2 --shard-by probe");
    ASSERT_EQ(r.status, 0) << r.output;
    if (r.output.find("windows 0,") != std::string::npos) {
      ++empty;
      EXPECT_NE(r.output.find("2 windows of the other shards left to them"), std::string::npos) << r.output;
      EXPECT_EQ(fs::file_size(path("p" + std::to_string(i) + ".lcmlog")), 0u);
    }
  }
  EXPECT_EQ(empty, 1);
  const Outcome m = shell(tipforce_bin() + " map --in " + path("p0.lcmlog") + " " + path("p1.lcmlog") + " --out " +
                          path("maps"));
  ASSERT_EQ(m.status, 0) << m.output;
  EXPECT_NE(m.output.find("is empty (a shard with no windows?): skipped"), std::string::npos) << m.output;
  EXPECT_NE(m.output.find("estimates: 2 "), std::string::npos) << m.output;
}

TEST_F(ShardCli, ShardOptionRefusesWhatItCannotDo) {
  const std::string config = write("c.toml", probe("afm1"));
  const std::string log = multi_probe_log(config, {"afm1"}, 2, 1);
  const std::map<std::string, std::string> bad = {
      {"--shard 2/2 --shard-by line", "shard index must be in [0, count - 1] = [0, 1], got 2"},
      {"--shard 0/0 --shard-by line", "shard count must be in [1, 4096], got 0"},
      {"--shard 1 --shard-by line", "expected I/N (shard I of N, counting from 0), got \"1\""},
      {"--shard 0/2x --shard-by line", "expected I/N"},
      {"--shard 0/2", "say how the log is split: --shard-by line"},
      {"--shard-by line", "--shard-by: needs --shard I/N"},
      {"--shard 0/2 --shard-by pixel", "--shard-by"},
  };
  for (const auto& [args, expected] : bad) {
    const Outcome r = shell(tipforce_bin() + " invert --config " + config + " --in " + log + " --out " + path("o.lcmlog") +
                            " " + args);
    EXPECT_NE(r.status, 0) << args;
    EXPECT_NE(r.output.find(expected), std::string::npos) << args << "\n" << r.output;
  }
}
