// The dashboard's --listen HOST:PORT: parsing and the URL it gives.
#pragma once

#include <optional>
#include <string>
#include <string_view>

namespace flexid::dashboard {

struct ListenAddress {
  std::string host;  // "127.0.0.1", "localhost" or an IPv6 address without brackets
  int port = 8080;   // 0: any free port
};

// HOST:PORT with HOST an IPv4 address (e.g. 127.0.0.1), "localhost" or a bracketed IPv6
// address ([::1]) and PORT 0-65535. nullopt with a one-line reason in *error otherwise.
std::optional<ListenAddress> ParseListenAddress(std::string_view text, std::string* error);

// "http://127.0.0.1:8080/", "http://[::1]:8080/".
std::string UrlOf(const std::string& host, int port);

// True for addresses only this host can reach (127.0.0.0/8, localhost, ::1).
bool IsLoopback(const std::string& host);

}  // namespace flexid::dashboard
