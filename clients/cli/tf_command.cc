// flexid tf show MODEL.json [--json]: poles, zeros, DC gain, damping and time constants
// of a model file; a T-S file shows each local model.
#include <iostream>
#include <nlohmann/json.hpp>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/tf_show.h"
#include "model/core/model_file.h"
#include "model/core/transfer_function.h"

namespace flexid::cli {
namespace {

using nlohmann::json;

json ComplexJson(std::complex<double> value) {
  return {{"re", value.real()}, {"im", value.imag()}};
}

json Finite(double value) { return std::isfinite(value) ? json(value) : json(nullptr); }

json TransferFunctionJson(const model::TransferFunction& tf) {
  json poles = json::array(), zeros = json::array(), modes = json::array();
  for (const auto& p : model::Poles(tf)) poles.push_back(ComplexJson(p));
  for (const auto& z : model::Zeros(tf)) zeros.push_back(ComplexJson(z));
  for (const model::Mode& m : model::Modes(tf))
    modes.push_back({{"pole", ComplexJson(m.pole)},
                     {"natural_frequency_rad_s", m.natural_frequency_rad_s},
                     {"damping_ratio", m.damping_ratio},
                     {"time_constant_s", Finite(m.time_constant_s)},
                     {"oscillatory", m.oscillatory}});
  return {{"num", tf.num},
          {"den", tf.den},
          {"delay_s", tf.delay_s},
          {"dc_gain", Finite(model::DcGain(tf))},
          {"stable", model::IsStable(tf)},
          {"poles", poles},
          {"zeros", zeros},
          {"modes", modes}};
}

void PrintTransferFunction(const model::TransferFunction& tf, std::ostream& out) {
  out << "  G(s) = e^(-" << FormatNumber(tf.delay_s) << " s) (" << FormatPolynomial(tf.num)
      << ") / (" << FormatPolynomial(tf.den) << ")\n";
  out << "  DC gain: " << FormatNumber(model::DcGain(tf)) << " per V"
      << "    dead time: " << FormatNumber(tf.delay_s) << " s"
      << "    stable: " << (model::IsStable(tf) ? "yes" : "NO") << "\n\n";
  Table modes({"pole", "wn rad/s", "damping", "tau s"});
  bool oscillatory = false;
  for (const model::Mode& m : model::Modes(tf)) {
    oscillatory = oscillatory || m.oscillatory;
    modes.AddRow({m.oscillatory ? FormatComplex(m.pole, 5) + " (pair)" : FormatComplex(m.pole, 5),
                  FormatNumber(m.natural_frequency_rad_s, 5), FormatNumber(m.damping_ratio, 4),
                  FormatNumber(m.time_constant_s, 5)});
  }
  modes.Print(out);
  const auto zeros = model::Zeros(tf);
  out << "\n  zeros:";
  if (zeros.empty()) out << " none";
  for (const auto& z : zeros) out << "  " << FormatComplex(z, 5);
  out << "\n";
  if (oscillatory)
    out << "  note: complex poles; the physics chain (Eqs. 11-13) predicts real, negative poles "
           "only, so the oscillatory mode is not explained by the electro-chemo-mechanical model\n";
}

void RunShow(const std::string& path, bool as_json) {
  const model::ModelDocument doc = model::ReadModelFile(path);
  if (as_json)
    std::cout << ModelPresentationJson(doc).dump(2) << '\n';
  else
    PrintModelPresentation(doc, path, std::cout);
}

}  // namespace

json ModelPresentationJson(const model::ModelDocument& doc) {
  if (doc.kind == model::ModelDocument::Kind::kTransferFunction) {
    json out = TransferFunctionJson(doc.tf);
    out["kind"] = "tf";
    return out;
  }
  json locals = json::array();
  for (const model::LocalModel& rule : doc.ts.rules) {
    json local = TransferFunctionJson(rule.tf);
    local["level_V"] = rule.level_V;
    local["membership"] = {{"shape", model::MembershipShapeName(rule.membership.shape)},
                           {"params", json::array()}};
    for (double p : rule.membership.params) local["membership"]["params"].push_back(Finite(p));
    locals.push_back(local);
  }
  return {{"kind", "ts_fuzzy"},
          {"scheduling", model::SchedulingVariableName(doc.ts.scheduling)},
          {"local_models", locals}};
}

void PrintModelPresentation(const model::ModelDocument& doc, const std::string& name,
                            std::ostream& out) {
  if (doc.kind == model::ModelDocument::Kind::kTransferFunction) {
    out << name << ": transfer function\n";
    PrintTransferFunction(doc.tf, out);
    return;
  }
  out << name << ": T-S fuzzy model, " << doc.ts.rules.size() << " rules, scheduled on "
      << model::SchedulingVariableName(doc.ts.scheduling) << "\n";
  for (size_t i = 0; i < doc.ts.rules.size(); ++i) {
    const model::LocalModel& rule = doc.ts.rules[i];
    out << "\nlocal model " << i + 1 << " at " << FormatNumber(rule.level_V) << " V ("
        << model::MembershipShapeName(rule.membership.shape) << " membership)\n";
    PrintTransferFunction(rule.tf, out);
  }
}

void RegisterTfCommand(CLI::App& app) {
  CLI::App* tf = app.add_subcommand("tf", "Inspect transfer-function and T-S model files");
  tf->require_subcommand(1);
  CLI::App* show = tf->add_subcommand("show", "Poles, zeros, DC gain, damping and time constants");
  auto path = std::make_shared<std::string>();
  auto as_json = std::make_shared<bool>(false);
  show->add_option("MODEL", *path, "Model file (flexid.model/1 JSON)")->required();
  show->add_flag("--json", *as_json, "Print one JSON document");
  show->footer("Example:\n  flexid tf show examples/seed-8V.json");
  show->callback([path, as_json] { RunShow(*path, *as_json); });
}

}  // namespace flexid::cli
