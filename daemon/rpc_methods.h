// The RPC methods flexidd answers, and which of them must be signed. rpc_methods.cc holds
// the table: each method's name, its access and its handler, side by side.
#pragma once

#include <string_view>
#include <vector>

namespace flexid::daemon {

enum class Access {
  kReadOnly,  // anyone may ask; an `auth` is ignored
  kSigned,    // changes data: refused unless signed (lcmtypes/message_auth.h)
};

struct RpcMethodAccess {
  std::string_view method;
  Access access;
};

// Every method of flexidd's table with its access, in the table's order.
std::vector<RpcMethodAccess> RpcMethodAccesses();

}  // namespace flexid::daemon
