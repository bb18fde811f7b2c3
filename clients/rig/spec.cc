#include "clients/rig/spec.h"

#include <charconv>
#include <cmath>

#include "model/core/errors.h"

namespace flexid::rig {
namespace {

std::string Quote(std::string_view text) { return "\"" + std::string(text) + "\""; }

std::string FormatValue(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof buffer, value);
  return std::string(buffer, result.ptr);
}

}  // namespace

std::optional<double> ParseFiniteNumber(std::string_view text) {
  double value = 0.0;
  const char* end = text.data() + text.size();
  const auto result = std::from_chars(text.data(), end, value);
  if (text.empty() || result.ec != std::errc{} || result.ptr != end || !std::isfinite(value))
    return std::nullopt;
  return value;
}

Spec Spec::Parse(std::string_view text, std::string kind) {
  Spec spec;
  spec.kind = std::move(kind);
  spec.text = std::string(text);
  const size_t colon = text.find(':');
  spec.name = std::string(text.substr(0, colon));
  if (spec.name.empty()) spec.Fail("empty specification (expected NAME[:KEY=VALUE,...])");
  if (colon == std::string_view::npos) return spec;
  std::string_view rest = text.substr(colon + 1);
  while (true) {
    const size_t comma = rest.find(',');
    const std::string_view item = rest.substr(0, comma);
    const size_t equals = item.find('=');
    if (equals == std::string_view::npos || equals == 0 || equals + 1 == item.size())
      spec.Fail("expected KEY=VALUE, got " + Quote(item));
    std::string key(item.substr(0, equals));
    for (const auto& [seen, value] : spec.params)
      if (seen == key) spec.Fail("key " + Quote(key) + " given twice");
    spec.params.emplace_back(std::move(key), std::string(item.substr(equals + 1)));
    if (comma == std::string_view::npos) break;
    rest = rest.substr(comma + 1);
  }
  return spec;
}

void Spec::Fail(const std::string& what) const {
  throw model::InputError(kind + " " + Quote(text) + ": " + what);
}

const std::string* SpecReader::Find(const std::string& key) {
  known_.push_back(key);
  for (const auto& [name, value] : spec_->params)
    if (name == key) return &value;
  return nullptr;
}

std::optional<double> SpecReader::Number(const std::string& key) {
  const std::string* text = Find(key);
  if (!text) return std::nullopt;
  const std::optional<double> value = ParseFiniteNumber(*text);
  if (!value) spec_->Fail(key + " is not a finite number: " + Quote(*text));
  return value;
}

std::optional<double> SpecReader::Positive(const std::string& key, std::string_view unit) {
  const std::optional<double> value = Number(key);
  if (value && !(*value > 0.0))
    spec_->Fail(key + " must be > 0" + (unit.empty() ? "" : " " + std::string(unit)) + " (got " +
                FormatValue(*value) + ")");
  return value;
}

std::optional<double> SpecReader::NonNegative(const std::string& key, std::string_view unit) {
  const std::optional<double> value = Number(key);
  if (value && !(*value >= 0.0))
    spec_->Fail(key + " must be >= 0" + (unit.empty() ? "" : " " + std::string(unit)) + " (got " +
                FormatValue(*value) + ")");
  return value;
}

std::optional<double> SpecReader::InRange(const std::string& key, double low, double high,
                                          bool include_ends) {
  const std::optional<double> value = Number(key);
  if (!value) return value;
  const bool inside =
      include_ends ? (*value >= low && *value <= high) : (*value > low && *value < high);
  if (!inside)
    spec_->Fail(key + " must be " + (include_ends ? ">= " : "> ") + FormatValue(low) + " and " +
                (include_ends ? "<= " : "< ") + FormatValue(high) + " (got " + FormatValue(*value) +
                ")");
  return value;
}

std::optional<int64_t> SpecReader::Count(const std::string& key) {
  const std::string* text = Find(key);
  if (!text) return std::nullopt;
  int64_t value = 0;
  const char* end = text->data() + text->size();
  const auto result = std::from_chars(text->data(), end, value);
  if (result.ec != std::errc{} || result.ptr != end || value <= 0)
    spec_->Fail(key + " must be a positive whole number (got " + Quote(*text) + ")");
  return value;
}

std::optional<uint64_t> SpecReader::WholeNumber(const std::string& key) {
  const std::string* text = Find(key);
  if (!text) return std::nullopt;
  uint64_t value = 0;
  const char* end = text->data() + text->size();
  const auto result = std::from_chars(text->data(), end, value);
  if (result.ec != std::errc{} || result.ptr != end)
    spec_->Fail(key + " must be a whole number >= 0 (got " + Quote(*text) + ")");
  return value;
}

std::optional<std::vector<double>> SpecReader::NumberList(const std::string& key) {
  const std::string* text = Find(key);
  if (!text) return std::nullopt;
  std::vector<double> values;
  std::string_view rest = *text;
  while (true) {
    const size_t slash = rest.find('/');
    const std::optional<double> value = ParseFiniteNumber(rest.substr(0, slash));
    if (!value)
      spec_->Fail(key + " is not a list of finite numbers separated by '/': " + Quote(*text));
    values.push_back(*value);
    if (slash == std::string_view::npos) break;
    rest = rest.substr(slash + 1);
  }
  return values;
}

void SpecReader::RejectUnknownKeys() const {
  for (const auto& [key, value] : spec_->params) {
    bool known = false;
    for (const std::string& name : known_) known = known || name == key;
    if (known) continue;
    std::string list;
    for (size_t i = 0; i < known_.size(); ++i)
      list += (i == 0 ? "" : i + 1 == known_.size() ? " and " : ", ") + known_[i];
    spec_->Fail("unknown key " + Quote(key) + " (" + spec_->name + " takes " +
                (known_.empty() ? "no parameters" : list) + ")");
  }
}

}  // namespace flexid::rig
