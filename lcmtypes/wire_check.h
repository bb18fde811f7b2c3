// Structural check of an encoded flexid message before lcm-gen's decoder sees it.
//
// LCM 1.3's generated C++ decoders check a string's length only against the bytes left,
// not for being positive: a crafted length of INT32_MIN makes decode() copy ~4 GB and the
// process dies. Every message that comes from the bus is therefore walked here first:
// the 8-byte type fingerprint, then each field in the order of its .lcm file (big-endian;
// a string is an int32 length counting its terminating NUL, then the bytes, NUL last and
// nowhere else; an array's length is the preceding count field). The layouts below must follow the
// .lcm files; tests/wire_check_test.cc encodes every type and checks that they do.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <initializer_list>

namespace flexid::wire {

enum class Field {
  kInt8,
  kInt16Count,
  kInt32,
  kInt64,
  kDouble,
  kString,
  kDoubleArray,
  kStringArray,
  kInt8Array,
  kInt64Array
};

// True if `data` holds exactly one message of this layout with well-formed strings and
// arrays (the fingerprint itself is checked by decode()).
inline bool WellFormed(const void* data, size_t size, std::initializer_list<Field> layout) {
  const auto* bytes = static_cast<const uint8_t*>(data);
  size_t pos = 8;  // fingerprint
  if (bytes == nullptr || size < pos) return false;
  int64_t count = 0;
  auto read_be = [&](size_t width, int64_t* value) {
    if (size - pos < width) return false;
    uint64_t v = 0;
    for (size_t i = 0; i < width; ++i) v = (v << 8) | bytes[pos + i];
    // Sign-extend.
    if (width < 8 && (v >> (8 * width - 1)) & 1) v |= ~uint64_t{0} << (8 * width);
    *value = static_cast<int64_t>(v);
    pos += width;
    return true;
  };
  // A string: an int32 length counting its NUL, then the bytes. NUL last and nowhere
  // else: LCM's encoders write strlen() bytes, so a string with an embedded NUL does not
  // survive decode -> encode (a reply echoing such a request_id would be sent with
  // unwritten bytes at its end).
  auto read_string = [&]() {
    int64_t length = 0;
    if (!read_be(4, &length) || length < 1 || static_cast<uint64_t>(length) > size - pos)
      return false;
    if (bytes[pos + static_cast<size_t>(length) - 1] != 0 ||
        std::memchr(bytes + pos, 0, static_cast<size_t>(length) - 1) != nullptr)
      return false;
    pos += static_cast<size_t>(length);
    return true;
  };
  for (Field field : layout) {
    int64_t value = 0;
    switch (field) {
      case Field::kInt8:
        if (!read_be(1, &value)) return false;
        break;
      case Field::kInt16Count:
        if (!read_be(2, &count) || count < 0) return false;
        break;
      case Field::kInt32:
        if (!read_be(4, &value)) return false;
        break;
      case Field::kInt64:
      case Field::kDouble:
        if (!read_be(8, &value)) return false;
        break;
      case Field::kString:
        if (!read_string()) return false;
        break;
      case Field::kDoubleArray:
      case Field::kInt64Array:
        if (static_cast<uint64_t>(count) > (size - pos) / 8) return false;
        pos += static_cast<size_t>(count) * 8;
        break;
      case Field::kInt8Array:
        if (static_cast<uint64_t>(count) > size - pos) return false;
        pos += static_cast<size_t>(count);
        break;
      case Field::kStringArray:
        for (int64_t i = 0; i < count; ++i)
          if (!read_string()) return false;
        break;
    }
  }
  return pos == size;
}

using F = Field;
inline constexpr std::initializer_list<Field> kVoltageSample = {F::kInt64, F::kString, F::kDouble};
inline constexpr std::initializer_list<Field> kDeflectionSample = {F::kInt64, F::kString,
                                                                   F::kDouble};
inline constexpr std::initializer_list<Field> kPrediction = {
    F::kInt64,  F::kString, F::kDouble, F::kDouble,     F::kDouble,
    F::kDouble, F::kInt32,  F::kInt32,  F::kInt16Count, F::kDoubleArray};
inline constexpr std::initializer_list<Field> kAlert = {F::kInt64,  F::kString, F::kString,
                                                        F::kInt8,   F::kInt64,  F::kInt64,
                                                        F::kDouble, F::kDouble, F::kString};
inline constexpr std::initializer_list<Field> kTrialControl = {F::kInt64, F::kString, F::kInt8,
                                                               F::kString};
inline constexpr std::initializer_list<Field> kTrialControl2 = {
    F::kInt64, F::kString, F::kInt8, F::kString, F::kInt64, F::kString, F::kString};
// utime .. mode, reference_mm, reference_utime, sent_utime, nonce, auth
inline constexpr std::initializer_list<Field> kVoltageCommand = {
    F::kInt64,  F::kString, F::kDouble, F::kInt64,  F::kString, F::kInt8,
    F::kDouble, F::kInt64,  F::kInt64,  F::kString, F::kString};
inline constexpr std::initializer_list<Field> kRpcRequest = {
    F::kInt64, F::kString, F::kString, F::kString, F::kString, F::kString, F::kString};
inline constexpr std::initializer_list<Field> kRpcReply = {F::kInt64, F::kString, F::kString,
                                                           F::kInt8,  F::kString, F::kString};
inline constexpr std::initializer_list<Field> kStatus = {
    F::kInt64, F::kString, F::kString,  // utime, daemon_id, version
    F::kInt64, F::kInt64,  F::kInt64,  F::kInt64, F::kInt64,
    F::kInt64,                                                // uptime .. rejected_nonfinite
    F::kInt64, F::kInt64,  F::kInt64,  F::kInt64, F::kInt64,  // .. alerts_raised
    F::kInt32, F::kInt32,  F::kInt8};
// utime, daemon_id, instance_id, the claims (ids, kinds, first seen), the peers (ids, heard).
inline constexpr std::initializer_list<Field> kOwnership = {
    F::kInt64,     F::kString,     F::kString,     F::kInt16Count,  F::kStringArray,
    F::kInt8Array, F::kInt64Array, F::kInt16Count, F::kStringArray, F::kInt64Array};

}  // namespace flexid::wire
