// flexidd's table of RPC methods against lcmtypes/message_auth.h's ChangesData(), the one
// list by which flexidd requires a signature and the clients sign: a method added to one
// and not the other would be refused, or answered unsigned.
#include "daemon/rpc_methods.h"

#include <gtest/gtest.h>

#include <set>
#include <string>

#include "lcmtypes/message_auth.h"

namespace flexid::daemon {
namespace {

TEST(RpcMethods, TheTableSaysSignedExactlyWhereChangesDataSaysSo) {
  for (const RpcMethodAccess& entry : RpcMethodAccesses())
    EXPECT_EQ(entry.access == Access::kSigned, auth::ChangesData(entry.method)) << entry.method;
}

TEST(RpcMethods, TheReadOnlyMethodsAreTheDocumentedOnes) {
  std::set<std::string> read_only;
  for (const RpcMethodAccess& entry : RpcMethodAccesses())
    if (entry.access == Access::kReadOnly) read_only.emplace(entry.method);
  // daemon/rpc.h and README "Security".
  EXPECT_EQ(read_only, (std::set<std::string>{"status", "actuators", "trials", "trial_samples",
                                              "models", "model", "alerts"}));
}

TEST(RpcMethods, EachMethodIsInTheTableOnce) {
  std::set<std::string> seen;
  for (const RpcMethodAccess& entry : RpcMethodAccesses())
    EXPECT_TRUE(seen.emplace(entry.method).second) << entry.method;
}

TEST(RpcMethods, AMethodNotInTheTableCountsAsChangingData) {
  EXPECT_TRUE(auth::ChangesData("no_such_method"));
}

}  // namespace
}  // namespace flexid::daemon
