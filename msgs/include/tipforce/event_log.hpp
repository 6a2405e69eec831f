#pragma once
// LCM log files, read and written by tipforce itself rather than through LCM's file provider,
// because LCM's reader takes the first damaged event header for the end of the log (the rest of a
// recording is silently lost) and LCM's writer does not report a full disk. Both `tipforce invert`
// and tipforced's file mode use these, with file:// URLs parsed and checked by the helpers below.
//
// The format is LCM's (lcm/eventlog.c), all integers big-endian, one record per event:
//   uint32 sync word 0xEDA1DA01, int64 eventnum, int64 timestamp (µs), int32 channel length,
//   int32 data length, the channel's bytes (no terminator), the data's bytes.
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace tipforce::lcmio {

inline constexpr std::uint32_t kLogSyncWord = 0xEDA1DA01;
// LCM refuses channel names longer than 63 bytes; a longer one in a log is damage, which helps
// to tell a real event header from four stray bytes that happen to equal the sync word.
inline constexpr std::int32_t kLogMaxChannelBytes = 255;
// Larger than any message tipforce accepts (a 1,000,000-sample window with a sampled drive is
// 8 MB); a header that claims more is damaged.
inline constexpr std::int64_t kLogMaxEventBytes = std::int64_t{1} << 30;

class LogError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct LogEvent {
  std::int64_t eventnum = 0;
  std::int64_t timestamp = 0;
  std::string channel;
  std::vector<std::uint8_t> data;
};

// A stretch of the file that was not an intact event and was skipped.
// Which file an open log is (device and inode).
struct FileIdentity {
  std::uint64_t device = 0;
  std::uint64_t inode = 0;
  bool operator==(const FileIdentity&) const = default;
};

struct LogDamage {
  std::uint64_t offset = 0;  // where the stretch starts
  std::uint64_t bytes = 0;   // how long it is
  std::string why;           // what was wrong at its start
};

// "skipped N damaged bytes at offset O (why)": how every reader reports a stretch it skipped.
std::string describe(const LogDamage& damage);

// Reads events in order. A damaged stretch (a broken sync word, an implausible header, a length
// that runs past the end of the file, a truncated last event) is skipped: the reader resyncs to
// the next sync word that starts a plausible header and goes on. Each skipped stretch is counted
// and kept until take_damage() for the caller to warn about.
class LogReader {
 public:
  // Throws LogError (with the path and the system's reason) when the file cannot be opened.
  explicit LogReader(const std::filesystem::path& path);
  ~LogReader();
  LogReader(const LogReader&) = delete;
  LogReader& operator=(const LogReader&) = delete;

  // The next intact event; nullopt at the end of the file or after a read error (see error()).
  std::optional<LogEvent> next();

  std::int64_t damaged_stretches() const { return damaged_; }
  // The stretches skipped since the last call.
  std::vector<LogDamage> take_damage();
  // Non-empty after an I/O error (not the end of the file).
  const std::string& error() const { return error_; }
  const FileIdentity& identity() const { return identity_; }

 private:
  bool read_exact(void* dst, std::size_t n);
  bool seek(std::uint64_t offset);
  void note_damage(std::uint64_t from, std::uint64_t to, const std::string& why);

  std::FILE* f_ = nullptr;
  std::string path_;
  std::uint64_t size_ = 0;
  std::uint64_t pos_ = 0;
  std::int64_t damaged_ = 0;
  std::vector<LogDamage> pending_damage_;
  std::string error_;
  FileIdentity identity_;
};

// Writes events, each with one write() (no user-space buffer), so a write error (a full disk, an
// I/O error) is seen at the event it hits, and what was written can be read along.
class LogWriter {
 public:
  // append = false truncates. Throws LogError when the file cannot be opened, or when it turns out
  // to be `must_not_be` (the input being read): that is checked on the opened file, before it is
  // truncated, so no path trick or race between a check and the open can empty the input.
  LogWriter(const std::filesystem::path& path, bool append, const FileIdentity* must_not_be = nullptr);
  ~LogWriter();
  LogWriter(const LogWriter&) = delete;
  LogWriter& operator=(const LogWriter&) = delete;

  // False on a write error; error() says what.
  bool write(std::string_view channel, std::int64_t timestamp, const void* data, std::size_t size);
  // Syncs to the device and closes; false (and error()) if this or any write failed. Idempotent.
  bool close();
  const std::string& error() const { return error_; }
  std::int64_t events_written() const { return next_eventnum_; }

 private:
  int fd_ = -1;
  std::string path_;
  std::vector<std::uint8_t> buffer_;
  std::int64_t next_eventnum_ = 0;
  std::string error_;
};

// A file:// LCM URL taken apart: the path, and the options after '?' (key=value, '&'-separated).
struct FileUrl {
  std::string path;
  std::map<std::string, std::string> options;
};
bool is_file_url(std::string_view url);
// Throws LogError for a URL that is not file:// or has an empty path.
FileUrl parse_file_url(std::string_view url);

// Whether the file begins as every LCM log does, with an event's sync word: tells a log damaged
// from its start from a file that never was a log (tipforce invert, map, tipforced alike).
bool starts_with_sync_word(const std::filesystem::path& path);

// True when a and b are the same file: the same device and inode where both exist (hard links,
// symbolic links and different spellings included), else the same resolved path.
bool same_file(const std::filesystem::path& a, const std::filesystem::path& b);

}  // namespace tipforce::lcmio
