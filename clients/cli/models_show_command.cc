// flexid models show: one stored model version, its summary (created, trials, fit figures,
// local models' fits, augmentations) and the model as `flexid tf show` presents it
// (tf_show.h); --out writes it as a model file for simulate/diagnose --model.
#include <algorithm>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/models_common.h"
#include "clients/cli/tf_show.h"
#include "model/core/errors.h"
#include "model/core/model_file.h"

namespace flexid::cli::models {
namespace {

struct ShowArgs {
  std::string actuator;
  std::string version = "0";
  std::string out;
  bool json = false;
};

void PrintSummary(const StoredVersion& v) {
  const json& s = v.summary;
  std::cout << v.name << (s.value("active", false) ? " (active)" : " (not active)") << "\n";
  const std::string lineage = LineageLong(s);
  std::cout << "  created " << IsoUtc(s.value("created_utime", int64_t{0})) << " by flexid "
            << s.value("flexid_version", std::string("?"))
            << (lineage.empty() ? ", identified from trials " : ", diagnosed trials ")
            << JoinNumbers(s.value("trials", json())) << "\n";
  if (!lineage.empty()) std::cout << "  " << lineage << "\n";
  const json fit = s.value("fit", json());
  if (fit.is_object())
    std::cout << "  fit " << Cell(NumberIn(fit, "fit_percent")) << " %, RMSE "
              << Cell(NumberIn(fit, "rmse_mm"), 3) << " mm on " << Cell(NumberIn(fit, "samples"), 9)
              << " samples; levels " << JoinNumbers(fit.value("levels_V", json())) << " V\n";
  const std::vector<Local> locals = LocalsOf(v.doc);
  const bool any_local_fit =
      std::any_of(locals.begin(), locals.end(), [](const Local& l) { return l.fit.is_object(); });
  if (locals.size() > 1 && any_local_fit) {
    Table table({"local model V", "fit %", "RMSE mm", "samples"});
    for (const Local& l : locals)
      table.AddRow({Cell(l.level_V), Cell(NumberIn(l.fit, "fit_percent")),
                    Cell(NumberIn(l.fit, "rmse_mm"), 3), Cell(NumberIn(l.fit, "samples"), 9)});
    table.Print(std::cout);
  }
  if (!v.doc.augmentations.empty()) {
    std::cout << "  augmentations:";
    for (const auto& a : v.doc.augmentations) std::cout << " " << a.effect;
    std::cout << "\n";
  }
  std::cout << "\n";
}

void RunShow(const ShowArgs& args) {
  RequireActuator(args.actuator);
  const StoredVersion v = FetchVersion(args.actuator, ParseVersion(args.version, "--version"));
  if (!args.out.empty()) {
    try {
      model::WriteModelFile(args.out, v.doc);
    } catch (const model::InputError& e) {
      throw OperationError(e.what());
    }
  }
  if (args.json) {
    json out = v.summary;
    out["model"] = v.document;
    std::cout << out.dump(2) << "\n";
    return;
  }
  PrintSummary(v);
  PrintModelPresentation(v.doc, v.name, std::cout);
  if (!args.out.empty()) std::cout << "\nwrote " << args.out << "\n";
}

}  // namespace

void AddShowCommand(CLI::App& models) {
  auto show = std::make_shared<ShowArgs>();
  CLI::App* show_cmd = models.add_subcommand(
      "show", "One model version: its summary and the model (poles, zeros, DC gain, ...)");
  show_cmd->add_option("--actuator", show->actuator, "Actuator id, e.g. S1")->required();
  show_cmd->add_option("--version", show->version, "Model version (default: the active one)");
  show_cmd->add_option("--out", show->out,
                       "Write the model as a model file (for simulate/diagnose --model)");
  show_cmd->add_flag("--json", show->json,
                     "Print the stored record: its summary and \"model\" (the model document)");
  show_cmd->footer(
      "Examples:\n  flexid models show --actuator S1\n"
      "  flexid models show --actuator S1 --version 2 --out s1-v2.json\n"
      "  flexid simulate --model s1-v2.json run.csv");
  show_cmd->callback([show] { RunShow(*show); });
}

}  // namespace flexid::cli::models
