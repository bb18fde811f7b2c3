// IdentifyGlobalTs in stages (internal to identify_global.cc and
// global_answer.cc): the search's state and one method per stage, in the order
// IdentifyGlobalTs runs them. The data and the structure's selection are in
// identify_global.cc; the answer (the refit at the full rate, the figures, the
// intervals, what the data cannot decide, the choice made again on every
// sample) in global_answer.cc. The maths is in identify_global.h.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "model/core/levels.h"
#include "model/core/recording.h"
#include "model/identify/global_fit.h"
#include "model/identify/identify_global.h"

namespace flexid::model::global_fit {

struct GlobalSearch {
  // Raising an estimate's orders (header): its choices are fixed, the dead time
  // with them. Throws InputError when there are no recordings.
  GlobalSearch(const std::vector<Recording> &data, const GlobalIdentifyOptions &given);

  const std::vector<Recording> &recordings;
  const GlobalEstimate *const raising;  // GlobalIdentifyOptions::raise_order_of
  GlobalIdentifyOptions options;        // as given, or as raising fixes them
  GlobalEstimate result;
  Problem problem;            // the data the structure is chosen on (every factor-th sample)
  Mask usable;                // the samples a fit may use
  LevelAnalysis merged;       // the recordings' levels and plateaus
  double longest_s = 0.0;     // the longest recording's duration
  Problem full;               // the data on every sample ...
  Mask full_usable;           // ... and their usable samples
  int factor = 1;             // the structure is chosen on every factor-th sample (Decimate)
  std::vector<double> knots;  // the initial knots: switching is checked between them
  std::optional<Selector> selector;
  bool orders_fixed = false;
  bool linear_pilot = false;        // a gain per knot did not switch plausibly (Select)
  GlobalStructure current;          // the structure chosen so far
  std::vector<double> current_all;  // the current structure fitted on all usable data
  StructureTrial current_trial;     // the current structure held out
  std::vector<std::string> reasons;
  std::optional<std::pair<double, double>> delay_profile_s;  // the dead time's interval
  FitResult final_fit;                           // the chosen structure on every usable sample
  std::vector<std::vector<double>> residual_mm;  // its residuals (NaN where not usable)

  // The data (identify_global.cc).
  void ReadData();
  void MarkUsable();
  void Coarsen();

  // The structure (identify_global.cc).
  void StartSelection();
  void RunStage(const std::string &stage, const std::vector<GlobalStructure> &candidates,
                const std::vector<std::vector<std::vector<double>>> &starts,
                const std::vector<bool> &also_screened = {});
  void Raise();
  void Select();
  void SplitDynamics();
  void ChooseRealisation();
  void ScanDeadTime();
  void ChooseOrders();
  std::vector<double> SmoothStart(const GlobalStructure &to_structure);
  void ChooseRules();
  void ChoosePremise();
  void DelayInterval();

  // The answer (global_answer.cc).
  void RefitAtFullRate();
  void FinalFit();
  void Intervals();
  void Explain();
  void WarnAboutLevels();
  std::optional<GlobalEstimate> ChooseAgainOnEverySample();
};

}  // namespace flexid::model::global_fit
