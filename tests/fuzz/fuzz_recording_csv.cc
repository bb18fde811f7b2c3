// Fuzz target: a recording CSV (model/core/recording.h, ParseRecordingCsv), as `flexid
// identify|simulate|diagnose` and `flexid trials import` read it.
//
// Invariants (abort otherwise): only model::InputError is thrown, its message starts with
// the source name; an accepted recording has at least 2 samples, equal column lengths,
// finite values and strictly increasing time; with require_deflection the deflection
// column is there.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "model/core/errors.h"
#include "model/core/recording.h"

namespace {

using flexid::model::InputError;
using flexid::model::Recording;

[[noreturn]] void Fail(const char* what) {
  std::fprintf(stderr, "fuzz_recording_csv: %s\n", what);
  std::abort();
}

void Check(std::string_view text, bool require_deflection) {
  const std::string name = "fuzz.csv";
  Recording recording;
  try {
    recording = flexid::model::ParseRecordingCsv(text, name, {require_deflection});
  } catch (const InputError& e) {
    if (std::string_view(e.what()).substr(0, name.size()) != name)
      Fail("an error message does not name the file");
    return;
  }
  const size_t n = recording.t_s.size();
  if (n < 2) Fail("accepted fewer than 2 samples");
  if (recording.voltage_V.size() != n) Fail("voltage column of another length");
  if (recording.deflection_mm.size() != n &&
      !(recording.deflection_mm.empty() && !require_deflection))
    Fail("deflection column of another length");
  for (size_t k = 0; k < n; ++k) {
    if (!std::isfinite(recording.t_s[k]) || !std::isfinite(recording.voltage_V[k]))
      Fail("accepted a non-finite time or voltage");
    if (!recording.deflection_mm.empty() && !std::isfinite(recording.deflection_mm[k]))
      Fail("accepted a non-finite deflection");
    if (k > 0 && !(recording.t_s[k] > recording.t_s[k - 1])) Fail("time not strictly increasing");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  Check(text, true);
  Check(text, false);
  return 0;
}
