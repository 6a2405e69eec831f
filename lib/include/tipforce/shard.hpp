#pragma once
// Sharding (issue 12): several tipforced on one window stream, or several `tipforce invert` on one
// log, each answer a disjoint share of the windows without talking to each other. Each computes
// the same pure function of the window's header, so they agree on who answers what.
#include <cstdint>
#include <string>
#include <string_view>

namespace tipforce {

enum class ShardBy {
  probe,  // a probe's whole stream goes to one shard: FNV-1a 64 of the probe name, mod count
  line,   // a scan line (pixel_y) goes to one shard: pixel_y mod count, so consecutive lines alternate
};

const char* to_string(ShardBy by);

// This process's share: windows with shard_of(...) == index. count = 1 (the default) is everything.
struct ShardSpec {
  int index = 0;
  int count = 1;
  ShardBy by = ShardBy::probe;

  bool sharded() const { return count > 1; }
  // The shard that answers a window of probe `probe` on scan line `pixel_y`. `probe` is the name
  // as it is answered (an estimate's probe field: a refused name in its escaped form), so that an
  // estimate seen on the estimate channel maps to the same shard as its window.
  int shard_of(std::string_view probe, std::int32_t pixel_y) const;
  bool owns(std::string_view probe, std::int32_t pixel_y) const { return shard_of(probe, pixel_y) == index; }
  // "2/4 by line", for log lines.
  std::string describe() const;
};

// Largest shard count accepted (a guard against typos: 1e6 shards is not a set-up anyone runs).
inline constexpr int kMaxShardCount = 4096;

// FNV-1a, 64 bits (offset basis 14695981039346656037, prime 1099511628211): stable across
// platforms, compilers and releases, unlike std::hash.
std::uint64_t fnv1a64(std::string_view bytes);

// Why `spec` cannot be used (count outside [1, kMaxShardCount], index outside [0, count)), or "".
std::string shard_problem(const ShardSpec& spec);

}  // namespace tipforce
