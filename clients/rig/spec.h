// The text form shared by --protocol and --effect: NAME[:KEY=VALUE,KEY=VALUE,...], e.g.
// "square:level=5,period=220,duty=0.5,cycles=5" or "back_relaxation:fraction=0.3,tau=60".
//
// Spec splits the text; SpecReader hands out typed values, checks each against its rule and
// finally rejects every key nobody asked for. All failures are model::InputError with one
// line that quotes the whole specification, e.g.
//   protocol "step:level=2": missing key "duration"
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace flexid::rig {

struct Spec {
  std::string kind;  // "protocol" or "effect": names the specification in error messages
  std::string text;  // as given
  std::string name;  // the part before ':'
  std::vector<std::pair<std::string, std::string>> params;  // in the order given

  // Splits TEXT. Throws InputError if it is empty, a parameter is not KEY=VALUE with a
  // non-empty key and value, or a key is given twice.
  static Spec Parse(std::string_view text, std::string kind);

  // Throws InputError "<kind> "<text>": <what>".
  [[noreturn]] void Fail(const std::string& what) const;
};

class SpecReader {
 public:
  explicit SpecReader(const Spec& spec) : spec_(&spec) {}

  // The value of KEY as a finite number; nullopt if absent. Throws if it is not one.
  std::optional<double> Number(const std::string& key);
  // As Number, and required to be > 0 ("must be > 0").
  std::optional<double> Positive(const std::string& key, std::string_view unit);
  // As Number, and required to be >= 0 ("must be >= 0").
  std::optional<double> NonNegative(const std::string& key, std::string_view unit);
  // As Number, and required to lie between LOW and HIGH, ends included or not
  // ("must be > 0 and < 1").
  std::optional<double> InRange(const std::string& key, double low, double high, bool include_ends);
  // A positive integer (e.g. a cycle count).
  std::optional<int64_t> Count(const std::string& key);
  // A whole number >= 0 up to 2^64 - 1 (e.g. a generator seed).
  std::optional<uint64_t> WholeNumber(const std::string& key);
  // Finite numbers separated by '/', at least one ("2/4/6/8").
  std::optional<std::vector<double>> NumberList(const std::string& key);

  // Throws "missing key" unless VALUE is set.
  template <typename T>
  T Required(const std::string& key, std::optional<T> value) const {
    if (!value) spec_->Fail("missing key \"" + key + "\"");
    return *std::move(value);
  }

  // Throws for the first key none of the calls above asked for, listing the known ones.
  void RejectUnknownKeys() const;

 private:
  const std::string* Find(const std::string& key);

  const Spec* spec_;
  std::vector<std::string> known_;  // keys asked for, in order
};

// Parses the whole of TEXT as a finite number (no surrounding spaces); nullopt otherwise.
std::optional<double> ParseFiniteNumber(std::string_view text);

}  // namespace flexid::rig
