#include "bus/lcm_url.h"

namespace flexid::bus {

std::string WithReceiveBuffer(const std::string& url, int64_t bytes) {
  if (url.rfind("udpm://", 0) != 0 || url.find("recv_buf_size") != std::string::npos) return url;
  return url + (url.find('?') == std::string::npos ? "?" : "&") +
         "recv_buf_size=" + std::to_string(bytes);
}

}  // namespace flexid::bus
