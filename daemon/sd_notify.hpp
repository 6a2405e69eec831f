#pragma once
// systemd's notify protocol, implemented directly (one datagram to $NOTIFY_SOCKET), so tipforced
// needs no libsystemd. Everything is a no-op when not started by systemd with Type=notify.
#include <chrono>
#include <optional>
#include <string_view>

namespace tipforce::daemon {

// Sends one state string ("READY=1", "WATCHDOG=1", "STOPPING=1", "STATUS=..."). Returns true if it
// was delivered, false when there is no $NOTIFY_SOCKET or sending failed, including when the
// socket's queue is full: it never blocks, and never throws.
bool sd_notify(std::string_view state);

// The watchdog interval systemd asks for ($WATCHDOG_USEC, if $WATCHDOG_PID is unset or ours);
// nullopt when the watchdog is off.
std::optional<std::chrono::microseconds> sd_watchdog_interval();

}  // namespace tipforce::daemon
