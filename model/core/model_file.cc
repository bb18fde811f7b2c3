#include "model/core/model_file.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <initializer_list>
#include <limits>
#include <stdexcept>

#include "model/core/errors.h"
#include "model/core/text_file.h"

namespace flexid::model {
namespace {

constexpr const char* kSchedulingChoices =
    "expected \"abs_voltage\", \"voltage\", \"abs_voltage_held\" or \"abs_voltage_delayed\"";

using nlohmann::json;
using nlohmann::ordered_json;

constexpr std::string_view kKindTransferFunction = "tf";
constexpr std::string_view kKindTsFuzzy = "ts_fuzzy";
constexpr int kMaxNestingLevels = 64;
constexpr std::size_t kMaxSyntaxMessageCharacters = 200;
constexpr double kInfinity = std::numeric_limits<double>::infinity();

constexpr std::string_view kCoefficientsExpected = "expected a non-empty array of finite numbers";

// Top-level members flexid reads and writes itself, per kind; all others are "extra".
constexpr std::array<std::string_view, 6> kTransferFunctionMembers = {
    "format", "kind", "num", "den", "delay_s", "augmentations"};
constexpr std::array<std::string_view, 5> kTsFuzzyMembers = {"format", "kind", "local_models",
                                                             "scheduling", "augmentations"};

bool IsInterpreted(ModelDocument::Kind kind, std::string_view key) {
  const auto contains = [key](const auto& members) {
    return std::find(members.begin(), members.end(), key) != members.end();
  };
  return kind == ModelDocument::Kind::kTsFuzzy ? contains(kTsFuzzyMembers)
                                               : contains(kTransferFunctionMembers);
}

// ---------------------------------------------------------------------------------------
// Message helpers

// 1-based line and column (in characters) of a byte offset.
std::pair<std::size_t, std::size_t> LineAndColumn(std::string_view text, std::size_t offset) {
  offset = std::min(offset, text.size());
  std::size_t line = 1;
  std::size_t line_start = 0;
  for (std::size_t i = 0; i < offset; ++i) {
    if (text[i] == '\n') {
      ++line;
      line_start = i + 1;
    }
  }
  return {line, CharacterColumn(text.substr(line_start), offset - line_start)};
}

[[noreturn]] void FailAt(const std::string& source, std::string_view text, std::size_t offset,
                         const std::string& problem) {
  const auto [line, column] = LineAndColumn(text, offset);
  throw InputError(source + ":" + std::to_string(line) + ":" + std::to_string(column) + ": " +
                   problem);
}

// nlohmann's message without its "[json.exception...] parse error at line L, column C: "
// prefix (we compute line and column in characters ourselves).
std::string SyntaxProblem(std::string_view what) {
  if (!what.empty() && what.front() == '[') {
    const std::size_t end = what.find("] ");
    if (end != std::string_view::npos) what.remove_prefix(end + 2);
  }
  if (what.substr(0, 11) == "parse error") {
    const std::size_t colon = what.find(": ");
    if (colon != std::string_view::npos) what.remove_prefix(colon + 2);
  }
  return Printable(what, kMaxSyntaxMessageCharacters, false);
}

// Byte offset of a number literal quoted in an out-of-range message, or npos.
std::size_t FindNumberLiteral(std::string_view text, std::string_view literal) {
  auto is_number_char = [](char c) {
    return (c >= '0' && c <= '9') || c == '.' || c == 'e' || c == 'E' || c == '+' || c == '-';
  };
  if (literal.empty()) return std::string_view::npos;
  for (std::size_t at = text.find(literal); at != std::string_view::npos;
       at = text.find(literal, at + 1)) {
    const bool starts = at == 0 || !is_number_char(text[at - 1]);
    const std::size_t end = at + literal.size();
    const bool ends = end == text.size() || !is_number_char(text[end]);
    if (starts && ends) return at;
  }
  return std::string_view::npos;
}

json ParseJsonText(std::string_view text, const std::string& source) {
  bool too_deep = false;
  const json::parser_callback_t limit_depth = [&too_deep](int depth, json::parse_event_t event,
                                                          json& /*parsed*/) {
    // depth is that of the enclosing container: the root object starts at depth 0.
    if ((event == json::parse_event_t::object_start || event == json::parse_event_t::array_start) &&
        depth >= kMaxNestingLevels) {
      too_deep = true;
    }
    return !too_deep;
  };
  json root;
  try {
    root = json::parse(text.begin(), text.end(), limit_depth, /*allow_exceptions=*/true,
                       /*ignore_comments=*/false);
  } catch (const json::parse_error& error) {
    FailAt(source, text, error.byte > 0 ? error.byte - 1 : 0, SyntaxProblem(error.what()));
  } catch (const json::exception& error) {
    // Number overflow ("number overflow parsing '1e400'") carries no position.
    const std::string_view what = error.what();
    const std::size_t open = what.find('\'');
    const std::size_t close = what.rfind('\'');
    if (open != std::string_view::npos && close > open) {
      const std::string_view literal = what.substr(open + 1, close - open - 1);
      const std::size_t at = FindNumberLiteral(text, literal);
      if (at != std::string_view::npos) {
        FailAt(source, text, at,
               "number out of range: " + Printable(literal, kMaxQuotedCharacters, false) +
                   " (numbers must be finite doubles)");
      }
    }
    throw InputError(source + ": " + SyntaxProblem(what));
  }
  if (too_deep) {
    throw InputError(source + ": JSON nesting deeper than " + std::to_string(kMaxNestingLevels) +
                     " levels");
  }
  return root;
}

// ---------------------------------------------------------------------------------------
// Reading the document. `pointer` is the JSON pointer (RFC 6901) of the value at hand;
// the root is "".

class DocumentReader {
 public:
  explicit DocumentReader(const std::string& source) : source_(source) {}

  [[noreturn]] void Fail(const std::string& pointer, const std::string& problem) const {
    throw InputError(source_ + ": " + (pointer.empty() ? "" : pointer + ": ") + problem);
  }

  const json& Required(const json& object, const std::string& key, const std::string& pointer,
                       std::string_view expected) const {
    const auto it = object.find(key);
    if (it == object.end()) {
      Fail(pointer + "/" + key, "missing (" + std::string(expected) + ")");
    }
    return *it;
  }

  const json& RequiredObject(const json& value, const std::string& pointer) const {
    if (!value.is_object()) Fail(pointer, std::string("expected an object, found ") + Type(value));
    return value;
  }

  std::string String(const json& value, const std::string& pointer,
                     std::string_view expected) const {
    if (!value.is_string()) {
      Fail(pointer, std::string(expected) + ", found " + Type(value));
    }
    return value.get<std::string>();
  }

  double FiniteNumber(const json& value, const std::string& pointer) const {
    if (!value.is_number())
      Fail(pointer, std::string("expected a finite number, found ") + Type(value));
    const double number = value.get<double>();
    if (!std::isfinite(number)) Fail(pointer, "expected a finite number");
    return number;
  }

  std::vector<double> Coefficients(const json& value, const std::string& pointer) const {
    if (!value.is_array() || value.empty()) {
      Fail(pointer, std::string(kCoefficientsExpected) + " (found " +
                        (value.is_array() ? std::string("an empty array") : Type(value)) + ")");
    }
    std::vector<double> coefficients;
    coefficients.reserve(value.size());
    for (std::size_t i = 0; i < value.size(); ++i) {
      const json& element = value[i];
      if (!element.is_number() || !std::isfinite(element.get<double>())) {
        Fail(pointer, std::string(kCoefficientsExpected) + " (element " + std::to_string(i) +
                          " is " + (element.is_number() ? "not finite" : Type(element)) + ")");
      }
      coefficients.push_back(element.get<double>());
    }
    return coefficients;
  }

  // num, den and delay_s of `object` at `pointer`.
  TransferFunction ReadTransferFunction(const json& object, const std::string& pointer) const {
    TransferFunction tf;
    tf.num =
        Coefficients(Required(object, "num", pointer, kCoefficientsExpected), pointer + "/num");
    tf.den =
        Coefficients(Required(object, "den", pointer, kCoefficientsExpected), pointer + "/den");
    if (tf.den.front() == 0.0) {
      Fail(pointer + "/den/0",
           "leading denominator coefficient is 0 (it must be non-zero, usually 1)");
    }
    if (const auto it = object.find("delay_s"); it != object.end()) {
      tf.delay_s = FiniteNumber(*it, pointer + "/delay_s");
      if (tf.delay_s < 0.0) Fail(pointer + "/delay_s", "dead time must be >= 0");
    }
    std::string why;
    if (!IsValid(tf, &why)) Fail(pointer, why);
    return tf;
  }

  Membership ReadMembership(const json& value, const std::string& pointer) const {
    RequiredObject(value, pointer);
    Membership membership;
    const std::string shape_name =
        String(Required(value, "shape", pointer, "expected a membership shape"), pointer + "/shape",
               "expected a membership shape (a string)");
    if (!ParseMembershipShape(shape_name, &membership.shape)) {
      Fail(pointer + "/shape", "unknown membership shape " + Quoted(shape_name) +
                                   " (expected \"triangular\", \"trapezoidal\", \"gaussian\" or "
                                   "\"sigmoid\")");
    }
    const std::string params_pointer = pointer + "/params";
    const json& params = Required(value, "params", pointer, "expected an array of numbers");
    if (!params.is_array()) {
      Fail(params_pointer, std::string("expected an array of numbers, found ") + Type(params));
    }
    const bool trapezoidal = membership.shape == MembershipShape::kTrapezoidal;
    for (std::size_t i = 0; i < params.size(); ++i) {
      const json& element = params[i];
      const std::string element_pointer = params_pointer + "/" + std::to_string(i);
      if (element.is_null() && trapezoidal && i < 4) {
        membership.params.push_back(i < 2 ? -kInfinity : kInfinity);
      } else if (element.is_null()) {
        Fail(element_pointer,
             "null (an infinite shoulder) is allowed only in the 4 parameters "
             "of a trapezoidal membership");
      } else {
        membership.params.push_back(FiniteNumber(element, element_pointer));
      }
    }
    std::string why;
    if (!IsValid(membership, &why) || !ShouldersValid(membership, &why)) Fail(pointer, why);
    return membership;
  }

  // A trapezoid's shoulder is a = b = -inf or c = d = +inf; a lone infinity has no meaning.
  static bool ShouldersValid(const Membership& membership, std::string* why) {
    if (membership.shape != MembershipShape::kTrapezoidal || membership.params.size() != 4) {
      return true;
    }
    const auto& p = membership.params;
    if (std::isinf(p[0]) != std::isinf(p[1]) || std::isinf(p[2]) != std::isinf(p[3])) {
      *why =
          "trapezoidal membership: a shoulder needs both a and b null (-infinity) or both c "
          "and d null (+infinity)";
      return false;
    }
    return true;
  }

  std::vector<Augmentation> ReadAugmentations(const json& value, const std::string& pointer) const {
    if (!value.is_array()) Fail(pointer, std::string("expected an array, found ") + Type(value));
    std::vector<Augmentation> augmentations;
    for (std::size_t i = 0; i < value.size(); ++i) {
      const std::string item_pointer = pointer + "/" + std::to_string(i);
      const json& item = RequiredObject(value[i], item_pointer);
      Augmentation augmentation;
      augmentation.effect =
          String(Required(item, "effect", item_pointer, "expected an effect name"),
                 item_pointer + "/effect", "expected an effect name (a string)");
      if (augmentation.effect.empty()) Fail(item_pointer + "/effect", "effect name is empty");
      if (const auto it = item.find("params"); it != item.end()) {
        RequiredObject(*it, item_pointer + "/params");
        augmentation.params = *it;
      }
      augmentations.push_back(std::move(augmentation));
    }
    return augmentations;
  }

  void ReadTsModel(const json& root, ModelDocument* document) const {
    const json& local_models =
        Required(root, "local_models", "", "expected a non-empty array of local models");
    if (!local_models.is_array() || local_models.empty()) {
      Fail("/local_models", std::string("expected a non-empty array of local models, found ") +
                                (local_models.is_array() ? "an empty array" : Type(local_models)));
    }
    TsModel& model = document->ts;
    model.rules.resize(local_models.size());
    document->local_extra.assign(local_models.size(), json::object());
    for (std::size_t i = 0; i < local_models.size(); ++i) {
      const std::string pointer = "/local_models/" + std::to_string(i);
      const json& item = RequiredObject(local_models[i], pointer);
      model.rules[i].level_V = FiniteNumber(
          Required(item, "level_V", pointer, "expected a finite number"), pointer + "/level_V");
      model.rules[i].tf = ReadTransferFunction(item, pointer);
      for (const auto& [key, member] : item.items()) {
        if (key != "level_V" && key != "num" && key != "den" && key != "delay_s") {
          document->local_extra[i][key] = member;
        }
      }
    }

    const json& scheduling = RequiredObject(
        Required(root, "scheduling", "", "expected an object with memberships"), "/scheduling");
    if (const auto it = scheduling.find("variable"); it != scheduling.end()) {
      const std::string name = String(*it, "/scheduling/variable", kSchedulingChoices);
      if (!ParseSchedulingVariable(name, &model.scheduling)) {
        Fail("/scheduling/variable",
             "unknown scheduling variable " + Quoted(name) + " (" + kSchedulingChoices + ")");
      }
    }
    if (const auto it = scheduling.find("rest_band_V"); it != scheduling.end()) {
      model.rest_band_V = FiniteNumber(*it, "/scheduling/rest_band_V");
      if (model.rest_band_V < 0.0) Fail("/scheduling/rest_band_V", "expected a number >= 0");
    }
    // abs_voltage_delayed: the premise's delay; by default the smallest dead time of the
    // local models (a global fit shares one dead time among the rules).
    if (const auto it = scheduling.find("delay_s"); it != scheduling.end()) {
      model.scheduling_delay_s = FiniteNumber(*it, "/scheduling/delay_s");
      if (model.scheduling_delay_s < 0.0) Fail("/scheduling/delay_s", "expected a number >= 0");
    } else if (model.scheduling == SchedulingVariable::kAbsVoltageDelayed) {
      model.scheduling_delay_s = model.rules.front().tf.delay_s;
      for (const LocalModel& rule : model.rules)
        model.scheduling_delay_s = std::min(model.scheduling_delay_s, rule.tf.delay_s);
    }
    // parallel: every rule driven by its share of the voltage (ts_fuzzy.h); frozen when
    // absent (every model file written before parallel rules existed).
    if (const auto it = scheduling.find("realisation"); it != scheduling.end()) {
      const std::string name =
          String(*it, "/scheduling/realisation", "expected \"frozen\" or \"parallel\"");
      if (!ParseTsRealisation(name, &model.realisation))
        Fail("/scheduling/realisation",
             "unknown realisation " + Quoted(name) + " (expected \"frozen\" or \"parallel\")");
    }
    const json& memberships = Required(scheduling, "memberships", "/scheduling",
                                       "expected one membership per local model");
    if (!memberships.is_array()) {
      Fail("/scheduling/memberships", std::string("expected an array, found ") + Type(memberships));
    }
    if (memberships.size() != local_models.size()) {
      Fail("/scheduling/memberships",
           std::to_string(memberships.size()) + " memberships for " +
               std::to_string(local_models.size()) +
               " local models (expected one per local model, in the same order)");
    }
    for (std::size_t i = 0; i < memberships.size(); ++i) {
      model.rules[i].membership =
          ReadMembership(memberships[i], "/scheduling/memberships/" + std::to_string(i));
    }
    std::string why;
    if (!IsValid(model, &why)) Fail("/local_models", why);
  }

  ModelDocument Read(const json& root) const {
    if (!root.is_object()) {
      Fail("", std::string("expected a JSON object at the top level, found ") + Type(root));
    }
    const std::string format =
        String(Required(root, "format", "", "expected \"" + std::string(kModelFormat) + "\""),
               "/format", "expected the string \"" + std::string(kModelFormat) + "\"");
    if (format != kModelFormat) {
      Fail("/format", "unsupported format " + Quoted(format) + " (this flexid reads " +
                          std::string(kModelFormat) + ")");
    }
    constexpr std::string_view kKindsExpected = "expected \"tf\" or \"ts_fuzzy\"";
    const std::string kind = String(Required(root, "kind", "", kKindsExpected), "/kind",
                                    std::string(kKindsExpected) + " (a string)");

    ModelDocument document;
    if (kind == kKindTransferFunction) {
      document.kind = ModelDocument::Kind::kTransferFunction;
      document.tf = ReadTransferFunction(root, "");
    } else if (kind == kKindTsFuzzy) {
      document.kind = ModelDocument::Kind::kTsFuzzy;
      ReadTsModel(root, &document);
    } else {
      Fail("/kind", "unknown kind " + Quoted(kind) + " (" + std::string(kKindsExpected) + ")");
    }
    if (const auto it = root.find("augmentations"); it != root.end()) {
      document.augmentations = ReadAugmentations(*it, "/augmentations");
    }
    for (const auto& [key, member] : root.items()) {
      if (!IsInterpreted(document.kind, key)) document.extra[key] = member;
    }
    return document;
  }

 private:
  static std::string Type(const json& value) {
    if (value.is_null()) return "null";
    if (value.is_array() || value.is_object()) return std::string("an ") + value.type_name();
    return std::string("a ") + value.type_name();
  }

  const std::string& source_;
};

// ---------------------------------------------------------------------------------------
// Writing

std::string_view KindName(ModelDocument::Kind kind) {
  return kind == ModelDocument::Kind::kTsFuzzy ? kKindTsFuzzy : kKindTransferFunction;
}

void CheckWritable(const ModelDocument& document) {
  auto fail = [](const std::string& why) {
    throw std::invalid_argument("model document cannot be written: " + why);
  };
  auto check_tf = [&](const TransferFunction& tf, const std::string& where) {
    std::string why;
    if (!IsValid(tf, &why)) fail(where + why);
    if (tf.den.front() == 0.0) fail(where + "leading denominator coefficient is 0");
  };
  std::string why;
  if (document.kind == ModelDocument::Kind::kTransferFunction) {
    check_tf(document.tf, "");
  } else {
    if (!IsValid(document.ts, &why)) fail(why);
    for (std::size_t i = 0; i < document.ts.rules.size(); ++i) {
      const std::string where = "local model " + std::to_string(i) + ": ";
      check_tf(document.ts.rules[i].tf, where);
      if (!DocumentReader::ShouldersValid(document.ts.rules[i].membership, &why)) fail(where + why);
    }
    if (!document.local_extra.empty()) {
      if (document.local_extra.size() != document.ts.rules.size()) {
        fail("local_extra has " + std::to_string(document.local_extra.size()) + " entries for " +
             std::to_string(document.ts.rules.size()) + " local models");
      }
      for (const json& extra : document.local_extra) {
        if (!extra.is_object() && !extra.is_null()) fail("a local_extra entry is not an object");
      }
    }
  }
  if (!document.extra.is_object() && !document.extra.is_null()) fail("extra is not an object");
  for (const Augmentation& augmentation : document.augmentations) {
    if (augmentation.effect.empty()) fail("an augmentation has no effect name");
    if (!augmentation.params.is_object() && !augmentation.params.is_null()) {
      fail("the params of augmentation " + Quoted(augmentation.effect) + " are not an object");
    }
  }
}

void PutTransferFunction(const TransferFunction& tf, json* object) {
  (*object)["num"] = tf.num;
  (*object)["den"] = tf.den;
  (*object)["delay_s"] = tf.delay_s;
}

json MembershipToJson(const Membership& membership) {
  json params = json::array();
  for (const double value : membership.params) {
    if (std::isinf(value)) {
      params.push_back(nullptr);  // a shoulder: -inf in a, b; +inf in c, d
    } else {
      params.push_back(value);
    }
  }
  return {{"shape", MembershipShapeName(membership.shape)}, {"params", std::move(params)}};
}

// `value` with the keys in `first` first, in that order, then the others (sorted).
ordered_json Ordered(const json& value, std::initializer_list<std::string_view> first) {
  if (!value.is_object()) return ordered_json(value);
  ordered_json out = ordered_json::object();
  for (const std::string_view key : first) {
    if (const auto it = value.find(key); it != value.end())
      out[std::string(key)] = ordered_json(*it);
  }
  for (const auto& [key, member] : value.items()) {
    if (std::find(first.begin(), first.end(), key) == first.end()) out[key] = ordered_json(member);
  }
  return out;
}

ordered_json OrderedForWriting(const json& document) {
  ordered_json out = Ordered(document, {"format", "kind", "num", "den", "delay_s", "local_models",
                                        "scheduling", "augmentations"});
  if (const auto it = document.find("local_models"); it != document.end() && it->is_array()) {
    ordered_json& local_models = out["local_models"];
    for (std::size_t i = 0; i < it->size(); ++i) {
      local_models[i] = Ordered((*it)[i], {"level_V", "num", "den", "delay_s"});
    }
  }
  if (const auto it = document.find("scheduling"); it != document.end() && it->is_object()) {
    out["scheduling"] =
        Ordered(*it, {"variable", "realisation", "delay_s", "rest_band_V", "memberships"});
    if (const auto m = it->find("memberships"); m != it->end() && m->is_array()) {
      for (std::size_t i = 0; i < m->size(); ++i) {
        out["scheduling"]["memberships"][i] = Ordered((*m)[i], {"shape", "params"});
      }
    }
  }
  if (const auto it = document.find("augmentations"); it != document.end() && it->is_array()) {
    for (std::size_t i = 0; i < it->size(); ++i) {
      out["augmentations"][i] = Ordered((*it)[i], {"effect", "params"});
    }
  }
  return out;
}

}  // namespace

ModelDocument ParseModelJson(std::string_view text, const std::string& source_name) {
  if (text.size() > kMaxModelFileBytes) {
    throw InputError(source_name + ": model file is too large (" + std::to_string(text.size()) +
                     " bytes; the limit is " + std::to_string(kMaxModelFileBytes >> 20) + " MiB)");
  }
  const json root = ParseJsonText(text, source_name);
  return DocumentReader(source_name).Read(root);
}

ModelDocument ReadModelFile(const std::string& path) {
  const std::string text = ReadWholeFile(path, kMaxModelFileBytes,
                                         "model file is too large (the limit is " +
                                             std::to_string(kMaxModelFileBytes >> 20) + " MiB)");
  return ParseModelJson(text, path);
}

json ModelToJson(const ModelDocument& document) {
  CheckWritable(document);
  json out = json::object();
  out["format"] = kModelFormat;
  out["kind"] = KindName(document.kind);
  if (document.kind == ModelDocument::Kind::kTransferFunction) {
    PutTransferFunction(document.tf, &out);
  } else {
    const TsModel& model = document.ts;
    json local_models = json::array();
    json memberships = json::array();
    for (std::size_t i = 0; i < model.rules.size(); ++i) {
      json local = json::object();
      if (!document.local_extra.empty() && document.local_extra[i].is_object()) {
        local = document.local_extra[i];
      }
      local["level_V"] = model.rules[i].level_V;
      PutTransferFunction(model.rules[i].tf, &local);
      local_models.push_back(std::move(local));
      memberships.push_back(MembershipToJson(model.rules[i].membership));
    }
    out["local_models"] = std::move(local_models);
    out["scheduling"] = {{"variable", SchedulingVariableName(model.scheduling)},
                         {"memberships", std::move(memberships)}};
    if (model.scheduling == SchedulingVariable::kAbsVoltageHeld)
      out["scheduling"]["rest_band_V"] = model.rest_band_V;
    if (model.scheduling == SchedulingVariable::kAbsVoltageDelayed)
      out["scheduling"]["delay_s"] = model.scheduling_delay_s;
    if (model.realisation == TsRealisation::kParallel)
      out["scheduling"]["realisation"] = TsRealisationName(model.realisation);
  }
  if (!document.augmentations.empty()) {
    json augmentations = json::array();
    for (const Augmentation& augmentation : document.augmentations) {
      augmentations.push_back(
          {{"effect", augmentation.effect},
           {"params", augmentation.params.is_null() ? json::object() : augmentation.params}});
    }
    out["augmentations"] = std::move(augmentations);
  }
  if (document.extra.is_object()) {
    for (const auto& [key, member] : document.extra.items()) {
      if (!IsInterpreted(document.kind, key)) out[key] = member;
    }
  }
  return out;
}

void WriteModelFile(const std::string& path, const ModelDocument& document) {
  const ordered_json ordered = OrderedForWriting(ModelToJson(document));
  std::string text = ordered.dump(2, ' ', false, ordered_json::error_handler_t::replace);
  text += '\n';
  WriteFileAtomically(path, text);
}

TsModel AsTsModel(const ModelDocument& document) {
  if (document.kind == ModelDocument::Kind::kTransferFunction) return SingleRule(document.tf);
  return document.ts;
}

ModelDocument FromTransferFunction(const TransferFunction& tf) {
  ModelDocument document;
  document.kind = ModelDocument::Kind::kTransferFunction;
  document.tf = tf;
  return document;
}

ModelDocument FromTsModel(const TsModel& model) {
  ModelDocument document;
  document.kind = ModelDocument::Kind::kTsFuzzy;
  document.ts = model;
  document.local_extra.assign(model.rules.size(), json::object());
  return document;
}

nlohmann::json FitFiguresToJson(const FitFigures& fit) {
  auto number = [](double v) {
    return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
  };
  nlohmann::json out = {{"samples", fit.samples},
                        {"fit_percent", number(fit.fit_percent)},
                        {"rmse_mm", number(fit.rmse_mm)}};
  if (fit.whiteness.max_lag > 0)
    out["whiteness"] = {{"passed", fit.whiteness.passed},
                        {"max_lag", fit.whiteness.max_lag},
                        {"ljung_box_q", fit.whiteness.ljung_box_q},
                        {"threshold_95", fit.whiteness.chi2_threshold}};
  if (fit.cross_correlation.max_lag > 0)
    out["input_residual_correlation"] = {{"passed", fit.cross_correlation.passed},
                                         {"max_lag", fit.cross_correlation.max_lag},
                                         {"max_abs", fit.cross_correlation.max_abs},
                                         {"bound_95", fit.cross_correlation.bound}};
  return out;
}

}  // namespace flexid::model
