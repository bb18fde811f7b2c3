// Subscribes a member function of a test's handler object through
// lcm::LCM::subscribeFunction, as flexid's own code subscribes. lcm::LCM::subscribe with a
// member function is avoided: GCC 12 miscompiles its pointer-to-member call on LCM's
// polymorphic subscription object (lcm-cpp-impl.hpp, LCMMHSubscription::cb_func) under
// -fsanitize=vptr, part of "undefined": the check reads a wrong pointer and reports a
// "member access within null pointer" (or crashes when built recoverable). clang and
// unsanitized builds run it correctly; the sanitizer build (deploy/sanitize) stopped on it.
#pragma once

#include <lcm/lcm-cpp.hpp>

#include <string>

namespace flexid::testing {

template <class Method>
struct LcmHandlerMethod;
template <class Handler, class Message>
struct LcmHandlerMethod<void (Handler::*)(const lcm::ReceiveBuffer*, const std::string&,
                                          const Message*)> {
  using HandlerType = Handler;
  using MessageType = Message;
};

// lcm.subscribe(channel, kMethod, handler), e.g. SubscribeMember<&Counter::On>(lcm, "X", &c).
template <auto kMethod>
lcm::Subscription* SubscribeMember(lcm::LCM& lcm, const std::string& channel,
                                   typename LcmHandlerMethod<decltype(kMethod)>::HandlerType* handler) {
  using Traits = LcmHandlerMethod<decltype(kMethod)>;
  using Handler = typename Traits::HandlerType;
  using Message = typename Traits::MessageType;
  void (*thunk)(const lcm::ReceiveBuffer*, const std::string&, const Message*, Handler*) =
      [](const lcm::ReceiveBuffer* buffer, const std::string& name, const Message* message,
         Handler* self) { (self->*kMethod)(buffer, name, message); };
  return lcm.subscribeFunction(channel, thunk, handler);
}

}  // namespace flexid::testing
