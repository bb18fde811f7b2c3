// Fuzz target: a model file (model/core/model_file.h, ParseModelJson), as `flexid simulate|tf
// show|diagnose --model` and flexidd read it.
//
// Invariants (abort otherwise): only model::InputError is thrown, its message starts with
// the source name; an accepted document can be written (ModelToJson does not throw), the
// written document reads back, and writing it again gives the same JSON; the T-S view of
// it (AsTsModel) has one rule per local model.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "model/core/errors.h"
#include "model/core/model_file.h"

namespace {

using flexid::model::InputError;
using flexid::model::ModelDocument;

[[noreturn]] void Fail(const char* what) {
  std::fprintf(stderr, "fuzz_model_json: %s\n", what);
  std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const std::string name = "fuzz.json";
  ModelDocument document;
  try {
    document = flexid::model::ParseModelJson(text, name);
  } catch (const InputError& e) {
    if (std::string_view(e.what()).substr(0, name.size()) != name)
      Fail("an error message does not name the file");
    return 0;
  }
  nlohmann::json written;
  try {
    written = flexid::model::ModelToJson(document);
  } catch (const std::invalid_argument& e) {
    std::fprintf(stderr, "fuzz_model_json: %s\n", e.what());
    Fail("an accepted document cannot be written");
  }
  ModelDocument again;
  try {
    again = flexid::model::ParseModelJson(written.dump(), "written.json");
  } catch (const InputError& e) {
    std::fprintf(stderr, "fuzz_model_json: %s\n", e.what());
    Fail("a written document does not read back");
  }
  if (flexid::model::ModelToJson(again) != written) Fail("write -> read -> write changed it");
  const auto ts = flexid::model::AsTsModel(document);
  if (document.kind == ModelDocument::Kind::kTsFuzzy && ts.rules.size() != document.ts.rules.size())
    Fail("AsTsModel lost rules");
  return 0;
}
