// LCM URLs as the programs on the flexid bus open them.
#pragma once

#include <cstdint>
#include <string>

namespace flexid::bus {

// `url` with the kernel receive buffer of a udpm socket set to `bytes`, unless the URL is
// not udpm or already sets recv_buf_size (the caller's word wins). The kernel caps it at
// net.core.rmem_max (x2); LCM warns when it does.
std::string WithReceiveBuffer(const std::string& url, int64_t bytes);

}  // namespace flexid::bus
