#include "tipforce/event_log.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <system_error>

namespace tipforce::lcmio {
namespace {

constexpr std::size_t kHeaderBytes = 4 + 8 + 8 + 4 + 4;

std::uint64_t load_be(const std::uint8_t* p, int n) {
  std::uint64_t v = 0;
  for (int i = 0; i < n; ++i) v = (v << 8) | p[i];
  return v;
}

void store_be(std::uint8_t* p, std::uint64_t v, int n) {
  for (int i = n - 1; i >= 0; --i) {
    p[i] = static_cast<std::uint8_t>(v & 0xff);
    v >>= 8;
  }
}

std::string system_reason(int err) { return std::generic_category().message(err); }

bool printable_channel(const std::string& c) {
  for (unsigned char ch : c)
    if (ch < 0x20 || ch > 0x7e) return false;
  return true;
}

}  // namespace

// ---- reading -----------------------------------------------------------------------------------

LogReader::LogReader(const std::filesystem::path& path) : path_(path.string()) {
  f_ = std::fopen(path_.c_str(), "rb");
  if (f_ == nullptr) throw LogError(path_ + ": cannot open the log for reading: " + system_reason(errno));
  struct stat st {};
  if (::fstat(::fileno(f_), &st) != 0 || !S_ISREG(st.st_mode)) {
    std::fclose(f_);
    f_ = nullptr;
    throw LogError(path_ + ": not a regular file");
  }
  size_ = static_cast<std::uint64_t>(st.st_size);
  identity_ = FileIdentity{static_cast<std::uint64_t>(st.st_dev), static_cast<std::uint64_t>(st.st_ino)};
}

LogReader::~LogReader() {
  if (f_ != nullptr) std::fclose(f_);
}

bool LogReader::read_exact(void* dst, std::size_t n) {
  const std::size_t got = std::fread(dst, 1, n, f_);
  pos_ += got;
  if (got == n) return true;
  if (std::ferror(f_)) error_ = path_ + ": read error at byte " + std::to_string(pos_) + ": " + system_reason(errno);
  return false;
}

bool LogReader::seek(std::uint64_t offset) {
  if (::fseeko(f_, static_cast<off_t>(offset), SEEK_SET) != 0) {
    error_ = path_ + ": cannot seek to byte " + std::to_string(offset) + ": " + system_reason(errno);
    return false;
  }
  pos_ = offset;
  return true;
}

void LogReader::note_damage(std::uint64_t from, std::uint64_t to, const std::string& why) {
  ++damaged_;
  pending_damage_.push_back(LogDamage{from, to - from, why});
}

std::vector<LogDamage> LogReader::take_damage() {
  std::vector<LogDamage> out;
  out.swap(pending_damage_);
  return out;
}

std::optional<LogEvent> LogReader::next() {
  if (f_ == nullptr || !error_.empty()) return std::nullopt;
  // A damaged stretch starts at damage_from and ends where the next intact event starts.
  std::optional<std::uint64_t> damage_from;
  std::string damage_why;
  auto damaged = [&](std::uint64_t at, const std::string& why) {
    if (!damage_from) {
      damage_from = at;
      damage_why = why;
    }
  };
  while (true) {
    // Find a sync word: at once for an intact log, byte by byte after damage.
    const std::uint64_t start = pos_;
    std::uint32_t word = 0;
    std::uint64_t have = 0;
    while (have < 4 || word != kLogSyncWord) {
      const int c = std::getc(f_);
      if (c == EOF) {
        if (std::ferror(f_)) {
          error_ = path_ + ": read error at byte " + std::to_string(pos_) + ": " + system_reason(errno);
          return std::nullopt;
        }
        if (have > 0) damaged(start, have < 4 ? "truncated event at the end of the log" : "no sync word");
        if (damage_from) note_damage(*damage_from, pos_, damage_why);
        return std::nullopt;
      }
      ++pos_;
      ++have;
      word = (word << 8) | static_cast<std::uint32_t>(c);
    }
    const std::uint64_t sync_at = pos_ - 4;
    if (sync_at != start) damaged(start, "no sync word where an event should start");

    std::array<std::uint8_t, kHeaderBytes - 4> h{};
    if (!read_exact(h.data(), h.size())) {
      if (!error_.empty()) return std::nullopt;
      damaged(sync_at, "truncated event header at the end of the log");
      note_damage(*damage_from, pos_, damage_why);
      return std::nullopt;
    }
    LogEvent ev;
    ev.eventnum = static_cast<std::int64_t>(load_be(h.data(), 8));
    ev.timestamp = static_cast<std::int64_t>(load_be(h.data() + 8, 8));
    const auto channel_len = static_cast<std::int32_t>(load_be(h.data() + 16, 4));
    const auto data_len = static_cast<std::int32_t>(load_be(h.data() + 20, 4));
    const std::uint64_t body_at = sync_at + kHeaderBytes;
    std::string why;
    if (channel_len <= 0 || channel_len > kLogMaxChannelBytes)
      why = "implausible channel length " + std::to_string(channel_len);
    else if (data_len < 0 || data_len > kLogMaxEventBytes)
      why = "implausible data length " + std::to_string(data_len);
    else if (body_at + static_cast<std::uint64_t>(channel_len) + static_cast<std::uint64_t>(data_len) > size_)
      why = "event of " + std::to_string(data_len) + " bytes runs past the end of the log";
    if (why.empty()) {
      ev.channel.resize(static_cast<std::size_t>(channel_len));
      if (!read_exact(ev.channel.data(), ev.channel.size())) {
        if (!error_.empty()) return std::nullopt;
        why = "truncated channel name";
      } else if (!printable_channel(ev.channel)) {
        why = "channel name with unprintable bytes";
      }
    }
    if (why.empty()) {
      ev.data.resize(static_cast<std::size_t>(data_len));
      if (!read_exact(ev.data.data(), ev.data.size())) {
        if (!error_.empty()) return std::nullopt;
        why = "truncated event data";
      }
    }
    if (why.empty()) {
      if (damage_from) note_damage(*damage_from, sync_at, damage_why);
      return ev;
    }
    // Not an event after all: the sync word was damage or stray bytes. Look again one byte on.
    damaged(sync_at, why);
    if (!seek(sync_at + 1)) return std::nullopt;
  }
}

// ---- writing -----------------------------------------------------------------------------------

LogWriter::LogWriter(const std::filesystem::path& path, bool append, const FileIdentity* must_not_be)
    : path_(path.string()) {
  // Opened without O_TRUNC: truncation waits until the file is known not to be the input.
  fd_ = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC | (append ? O_APPEND : 0), 0644);
  if (fd_ < 0) throw LogError(path_ + ": cannot open the log for writing: " + system_reason(errno));
  struct stat st {};
  if (::fstat(fd_, &st) != 0) {
    const int err = errno;
    ::close(fd_);
    fd_ = -1;
    throw LogError(path_ + ": cannot open the log for writing: " + system_reason(err));
  }
  const FileIdentity opened{static_cast<std::uint64_t>(st.st_dev), static_cast<std::uint64_t>(st.st_ino)};
  if (must_not_be != nullptr && opened == *must_not_be) {
    ::close(fd_);
    fd_ = -1;
    throw LogError(path_ + ": is the input log (the same file); writing there would destroy the windows being read");
  }
  // Devices and pipes cannot be truncated, which is no error.
  if (!append && S_ISREG(st.st_mode) && ::ftruncate(fd_, 0) != 0) {
    const int err = errno;
    ::close(fd_);
    fd_ = -1;
    throw LogError(path_ + ": cannot truncate the log: " + system_reason(err));
  }
}

LogWriter::~LogWriter() { close(); }

bool LogWriter::write(std::string_view channel, std::int64_t timestamp, const void* data, std::size_t size) {
  if (fd_ < 0) {
    if (error_.empty()) error_ = path_ + ": the log is closed";
    return false;
  }
  // One buffer, one write() per event (no stdio buffer): an error is seen at the event it hits
  // and nothing is left half-written in a buffer to resurface later.
  buffer_.resize(kHeaderBytes + channel.size() + size);
  std::uint8_t* h = buffer_.data();
  store_be(h, kLogSyncWord, 4);
  store_be(h + 4, static_cast<std::uint64_t>(next_eventnum_), 8);
  store_be(h + 12, static_cast<std::uint64_t>(timestamp), 8);
  store_be(h + 20, channel.size(), 4);
  store_be(h + 24, size, 4);
  std::memcpy(h + kHeaderBytes, channel.data(), channel.size());
  if (size > 0) std::memcpy(h + kHeaderBytes + channel.size(), data, size);
  const off_t before = ::lseek(fd_, 0, SEEK_CUR);
  std::size_t done = 0;
  while (done < buffer_.size()) {
    const ssize_t n = ::write(fd_, buffer_.data() + done, buffer_.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      error_ = path_ + ": write failed: " + system_reason(n < 0 ? errno : EIO);
      // A partly written event would hide every later one from LCM's own reader: cut the file
      // back to the last whole event (not possible on devices and pipes, where it does not matter).
      if (done > 0 && before >= 0) (void)::ftruncate(fd_, before);
      if (before >= 0) (void)::lseek(fd_, before, SEEK_SET);
      return false;
    }
    done += static_cast<std::size_t>(n);
  }
  ++next_eventnum_;
  return true;
}

bool LogWriter::close() {
  if (fd_ < 0) return error_.empty();
  int err = 0;
  // Durable before success is reported; devices and pipes cannot be synced, which is no error.
  if (::fsync(fd_) != 0 && errno != EINVAL && errno != EROFS) err = errno;
  if (::close(fd_) != 0 && err == 0) err = errno;
  fd_ = -1;
  if (err != 0 && error_.empty()) error_ = path_ + ": closing the log failed: " + system_reason(err);
  return error_.empty();
}

// ---- URLs and file identity ----------------------------------------------------------------------

bool is_file_url(std::string_view url) { return url.rfind("file://", 0) == 0; }

FileUrl parse_file_url(std::string_view url) {
  if (!is_file_url(url)) throw LogError("not a file:// URL: \"" + std::string(url) + "\"");
  FileUrl out;
  std::string_view rest = url.substr(7);
  const auto q = rest.find('?');
  out.path = std::string(rest.substr(0, q));
  if (out.path.empty()) throw LogError("file:// URL without a path: \"" + std::string(url) + "\"");
  if (q != std::string_view::npos) {
    std::string_view query = rest.substr(q + 1);
    while (!query.empty()) {
      const auto amp = query.find('&');
      std::string_view item = query.substr(0, amp);
      const auto eq = item.find('=');
      if (!item.empty())
        out.options[std::string(item.substr(0, eq))] =
            eq == std::string_view::npos ? std::string() : std::string(item.substr(eq + 1));
      if (amp == std::string_view::npos) break;
      query.remove_prefix(amp + 1);
    }
  }
  return out;
}

std::string describe(const LogDamage& d) {
  return "skipped " + std::to_string(d.bytes) + " damaged bytes at offset " + std::to_string(d.offset) + " (" + d.why + ")";
}

bool starts_with_sync_word(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char b[4] = {};
  if (!in.read(reinterpret_cast<char*>(b), sizeof b)) return false;
  const std::uint32_t word = (std::uint32_t{b[0]} << 24) | (std::uint32_t{b[1]} << 16) | (std::uint32_t{b[2]} << 8) | b[3];
  return word == kLogSyncWord;
}

bool same_file(const std::filesystem::path& a, const std::filesystem::path& b) {
  struct stat sa {}, sb {};
  if (::stat(a.c_str(), &sa) == 0 && ::stat(b.c_str(), &sb) == 0)
    return sa.st_dev == sb.st_dev && sa.st_ino == sb.st_ino;
  // One of them does not exist (yet): compare where the paths lead, through every symbolic link
  // that does exist.
  std::error_code ea, eb;
  const auto ca = std::filesystem::weakly_canonical(std::filesystem::absolute(a, ea), ea);
  const auto cb = std::filesystem::weakly_canonical(std::filesystem::absolute(b, eb), eb);
  if (ea || eb) return a.lexically_normal() == b.lexically_normal();
  return ca == cb;
}

}  // namespace tipforce::lcmio
