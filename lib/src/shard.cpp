#include "tipforce/shard.hpp"

namespace tipforce {

const char* to_string(ShardBy by) { return by == ShardBy::line ? "line" : "probe"; }

std::uint64_t fnv1a64(std::string_view bytes) {
  std::uint64_t h = 14695981039346656037ull;
  for (const char c : bytes) {
    h ^= static_cast<unsigned char>(c);
    h *= 1099511628211ull;
  }
  return h;
}

int ShardSpec::shard_of(std::string_view probe, std::int32_t pixel_y) const {
  if (count <= 1) return 0;
  if (by == ShardBy::line) {
    // Plain modulo rather than a hash: a scan's consecutive lines alternate between the shards, so
    // each is busy all the time and the shares are equal to within a line. Negative lines too.
    const std::int64_t r = static_cast<std::int64_t>(pixel_y) % count;
    return static_cast<int>(r < 0 ? r + count : r);
  }
  return static_cast<int>(fnv1a64(probe) % static_cast<std::uint64_t>(count));
}

std::string ShardSpec::describe() const {
  return std::to_string(index) + "/" + std::to_string(count) + " by " + to_string(by);
}

std::string shard_problem(const ShardSpec& spec) {
  if (spec.count < 1 || spec.count > kMaxShardCount)
    return "shard count must be in [1, " + std::to_string(kMaxShardCount) + "], got " + std::to_string(spec.count);
  if (spec.index < 0 || spec.index >= spec.count)
    return "shard index must be in [0, count - 1] = [0, " + std::to_string(spec.count - 1) + "], got " +
           std::to_string(spec.index);
  return {};
}

}  // namespace tipforce
