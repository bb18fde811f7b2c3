// flexid models diff: two model versions (or model files) side by side: per local model
// (matched by level_V) DC gain, steady deflection, dead time, slowest time constant, poles
// and fit figures; and both models' step responses from rest at every level, with their
// largest difference in mm. Changes are B - A.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/models_common.h"
#include "model/core/model_file.h"
#include "model/core/simulate.h"
#include "model/core/transfer_function.h"

namespace flexid::cli::models {
namespace {

json Number(double value) { return std::isfinite(value) ? json(value) : json(nullptr); }

// "+0.8" / "-0.011": a change with its sign.
std::string Signed(double value, int significant = 3) {
  if (!std::isfinite(value)) return "-";
  return (value > 0 ? "+" : "") + FormatNumber(value, significant);
}

// Decay time of the slowest mode, s (NaN if none is finite).
double SlowestTimeConstant_s(const model::TransferFunction& tf) {
  double slowest = NAN;
  for (const model::Mode& m : model::Modes(tf))
    if (std::isfinite(m.time_constant_s) && m.time_constant_s > 0)
      slowest = std::isnan(slowest) ? m.time_constant_s : std::max(slowest, m.time_constant_s);
  return slowest;
}

// Poles, a complex pair once as "re +- im j".
std::string PolesText(const model::TransferFunction& tf) {
  std::string text;
  for (const auto& p : model::Poles(tf)) {
    if (p.imag() < 0) continue;
    if (!text.empty()) text += ", ";
    text += FormatNumber(p.real(), 4);
    if (p.imag() > 0) text += " +- " + FormatNumber(p.imag(), 4) + "j";
  }
  return text.empty() ? "none" : text;
}

json PolesJson(const model::TransferFunction& tf) {
  json out = json::array();
  for (const auto& p : model::Poles(tf)) out.push_back({{"re", p.real()}, {"im", p.imag()}});
  return out;
}

struct DiffArgs {
  std::string actuator;
  std::string a, b;
  bool json = false;
};

// One side of a comparison: a stored version or a model file.
struct Side {
  std::string label;  // column heading: "v3" or the file name
  std::string title;  // "S1 model v3" or the path
  json summary;       // stored summary, or null for a file
  model::ModelDocument doc;
  json fit;  // overall fit figures, or null
};

Side LoadSide(const std::string& actuator, const std::string& token) {
  Side side;
  const bool looks_like_version =
      token == "active" ||
      (!token.empty() && token.find_first_not_of("vV0123456789") == std::string::npos &&
       token.find_first_of("0123456789") != std::string::npos);
  if (looks_like_version) {
    if (actuator.empty())
      throw UsageError("\"" + token + "\" is a model version: name the actuator with --actuator");
    const StoredVersion v = FetchVersion(actuator, ParseVersion(token, "version"));
    side.summary = v.summary;
    side.doc = v.doc;
    side.title = v.name;
    side.label = "v" + std::to_string(v.summary.value("version", 0));
    side.fit = v.summary.value("fit", json());
    if (!side.fit.is_object()) side.fit = v.doc.extra.value("fit", json());
    return side;
  }
  side.doc = model::ReadModelFile(token);
  side.title = token;
  side.label = std::filesystem::path(token).filename().string();
  side.fit = side.doc.extra.value("fit", json());
  return side;
}

json SideJson(const Side& s) {
  json out = {{"label", s.label}, {"title", s.title}};
  if (s.summary.is_object()) {
    out["actuator"] = s.summary.value("actuator", "");
    out["version"] = s.summary.value("version", 0);
    out["created_utime"] = s.summary.value("created_utime", int64_t{0});
    out["active"] = s.summary.value("active", false);
    out["trials"] = s.summary.value("trials", json::array());
  } else {
    out["file"] = s.title;
  }
  out["kind"] = s.doc.kind == model::ModelDocument::Kind::kTsFuzzy ? "ts_fuzzy" : "tf";
  json levels = json::array();
  for (const Local& l : LocalsOf(s.doc)) levels.push_back(Number(l.level_V));
  out["levels_V"] = levels;
  out["fit"] = s.fit.is_object() ? s.fit : json();
  json augmentations = json::array();
  for (const auto& a : s.doc.augmentations) augmentations.push_back(a.effect);
  out["augmentations"] = augmentations;
  return out;
}

// Pairs of local models with the same level (within max(0.5 V, 10 %)); a side's index is
// -1 where the other side has no model at that level. A single model of unknown level is
// paired with the other side's single model.
std::vector<std::pair<int, int>> MatchLocals(const std::vector<Local>& a,
                                             const std::vector<Local>& b) {
  std::vector<std::pair<int, int>> pairs;
  std::vector<bool> used(b.size(), false);
  for (size_t i = 0; i < a.size(); ++i) {
    int best = -1;
    double best_distance = INFINITY;
    for (size_t j = 0; j < b.size(); ++j) {
      if (used[j]) continue;
      double distance = std::abs(a[i].level_V - b[j].level_V);
      const bool unknown = std::isnan(a[i].level_V) || std::isnan(b[j].level_V);
      if (unknown) {
        if (a.size() != 1 || b.size() != 1) continue;
        distance = 0.0;
      } else if (distance > std::max(0.5, 0.1 * std::abs(a[i].level_V))) {
        continue;
      }
      if (distance < best_distance) {
        best_distance = distance;
        best = static_cast<int>(j);
      }
    }
    if (best >= 0) used[static_cast<size_t>(best)] = true;
    pairs.emplace_back(static_cast<int>(i), best);
  }
  for (size_t j = 0; j < b.size(); ++j)
    if (!used[j]) pairs.emplace_back(-1, static_cast<int>(j));
  std::sort(pairs.begin(), pairs.end(), [&](const auto& x, const auto& y) {
    const double lx = x.first >= 0 ? a[x.first].level_V : b[x.second].level_V;
    const double ly = y.first >= 0 ? a[y.first].level_V : b[y.second].level_V;
    return lx < ly;
  });
  return pairs;
}

json LocalJson(const Local& l) {
  const double gain = model::DcGain(l.tf);
  json out = {{"level_V", Number(l.level_V)},
              {"dc_gain_mm_per_V", Number(gain)},
              {"steady_deflection_mm", Number(gain * l.level_V)},
              {"delay_s", l.tf.delay_s},
              {"slowest_time_constant_s", Number(SlowestTimeConstant_s(l.tf))},
              {"stable", model::IsStable(l.tf)},
              {"poles", PolesJson(l.tf)},
              {"num", l.tf.num},
              {"den", l.tf.den}};
  out["fit"] = l.fit.is_object() ? l.fit : json();
  return out;
}

// Both models' responses, from rest, to the same step of step_V volts.
json StepComparison(const model::TsModel& a, const model::TsModel& b, double step_V,
                    double horizon_s) {
  const double dt_s = std::min(horizon_s / 2000.0, 0.05);
  const auto n = static_cast<size_t>(std::ceil(horizon_s / dt_s)) + 1;
  std::vector<double> t_s(n), volts(n, step_V);
  for (size_t k = 0; k < n; ++k) t_s[k] = dt_s * static_cast<double>(k);
  std::vector<double> ya, yb;
  try {
    ya = model::Simulate(a, t_s, volts);
    yb = model::Simulate(b, t_s, volts);
  } catch (const std::invalid_argument& e) {
    throw OperationError(std::string("cannot simulate the step: ") + e.what());
  }
  double largest = 0.0, at_s = 0.0, peak_a = 0.0, peak_b = 0.0;
  bool finite = true;
  for (size_t k = 0; k < n; ++k) {
    if (!std::isfinite(ya[k]) || !std::isfinite(yb[k])) {
      finite = false;
      break;
    }
    peak_a = std::max(peak_a, std::abs(ya[k]));
    peak_b = std::max(peak_b, std::abs(yb[k]));
    const double d = std::abs(ya[k] - yb[k]);
    if (d > largest) {
      largest = d;
      at_s = t_s[k];
    }
  }
  if (!finite) return {{"step_V", step_V}, {"horizon_s", horizon_s}, {"diverges", true}};
  return {
      {"step_V", step_V},
      {"horizon_s", horizon_s},
      {"diverges", false},
      {"final_a_mm", ya.back()},
      {"final_b_mm", yb.back()},
      {"peak_a_mm", peak_a},
      {"peak_b_mm", peak_b},
      {"max_abs_difference_mm", largest},
      {"at_t_s", at_s},
      {"max_abs_difference_percent_of_peak", Number(100.0 * largest / std::max(peak_a, peak_b))}};
}

json DiffJson(const Side& a, const Side& b) {
  const std::vector<Local> la = LocalsOf(a.doc), lb = LocalsOf(b.doc);
  json out = {{"a", SideJson(a)}, {"b", SideJson(b)}};
  for (const auto& [key, side] : {std::pair{"a", &a}, std::pair{"b", &b}}) {
    json augmentations = json::array();
    for (const model::Augmentation& aug : side->doc.augmentations)
      augmentations.push_back({{"effect", aug.effect}, {"params", aug.params}});
    out[key]["augmentations"] = augmentations;
    out[key]["lineage"] =
        side->summary.is_object() ? side->summary.value("lineage", json()) : json();
  }
  if (a.fit.is_object() && b.fit.is_object())
    out["fit_change"] = {
        {"fit_percent", Number(NumberIn(b.fit, "fit_percent") - NumberIn(a.fit, "fit_percent"))},
        {"rmse_mm", Number(NumberIn(b.fit, "rmse_mm") - NumberIn(a.fit, "rmse_mm"))}};
  else
    out["fit_change"] = nullptr;
  json locals = json::array();
  std::vector<double> levels;
  for (const auto& [i, j] : MatchLocals(la, lb)) {
    json entry;
    const Local* x = i >= 0 ? &la[static_cast<size_t>(i)] : nullptr;
    const Local* y = j >= 0 ? &lb[static_cast<size_t>(j)] : nullptr;
    const double level = x && std::isfinite(x->level_V) ? x->level_V : y ? y->level_V : NAN;
    entry["level_V"] = Number(level);
    entry["a"] = x ? LocalJson(*x) : json();
    entry["b"] = y ? LocalJson(*y) : json();
    if (x && y) {
      const double ga = model::DcGain(x->tf), gb = model::DcGain(y->tf);
      json change = {{"dc_gain_percent", Number(100.0 * (gb - ga) / std::abs(ga))},
                     {"dc_gain_mm_per_V", Number(gb - ga)},
                     {"delay_s", y->tf.delay_s - x->tf.delay_s},
                     {"slowest_time_constant_s",
                      Number(SlowestTimeConstant_s(y->tf) - SlowestTimeConstant_s(x->tf))}};
      if (x->fit.is_object() && y->fit.is_object()) {
        change["fit_percent"] =
            Number(NumberIn(y->fit, "fit_percent") - NumberIn(x->fit, "fit_percent"));
        change["rmse_mm"] = Number(NumberIn(y->fit, "rmse_mm") - NumberIn(x->fit, "rmse_mm"));
      }
      entry["change"] = change;
    } else {
      entry["change"] = nullptr;
    }
    locals.push_back(entry);
    levels.push_back(std::isfinite(level) && level != 0.0 ? level : 1.0);
  }
  out["local_models"] = locals;
  // Long enough for the slowest mode of either model to settle (5 time constants after
  // the longer dead time), at least 10 s and at most an hour.
  double slowest = 0.0, delay = 0.0;
  for (const auto* side : {&la, &lb})
    for (const Local& l : *side) {
      const double tau = SlowestTimeConstant_s(l.tf);
      if (std::isfinite(tau)) slowest = std::max(slowest, tau);
      delay = std::max(delay, l.tf.delay_s);
    }
  const double horizon_s = std::clamp(5.0 * slowest + delay, 10.0, 3600.0);
  std::sort(levels.begin(), levels.end());
  levels.erase(std::unique(levels.begin(), levels.end()), levels.end());
  const model::TsModel ma = model::AsTsModel(a.doc), mb = model::AsTsModel(b.doc);
  json steps = json::array();
  for (double level : levels) steps.push_back(StepComparison(ma, mb, level, horizon_s));
  out["step_responses"] = steps;
  return out;
}

std::string FitPercentChange(double a, double b) {
  return std::isfinite(a) && std::isfinite(b) ? Signed(b - a, 3) + " pp" : "";
}
std::string MmChange(double a, double b) {
  return std::isfinite(a) && std::isfinite(b) ? Signed(b - a, 3) + " mm" : "";
}
std::string SecondsChange(double a, double b) {
  return std::isfinite(a) && std::isfinite(b) ? Signed(b - a, 3) + " s" : "";
}
std::string PercentChange(double a, double b) {
  return std::isfinite(a) && std::isfinite(b) && a != 0.0
             ? Signed(100.0 * (b - a) / std::abs(a), 3) + " %"
             : "";
}

void PrintDiff(const Side& a, const Side& b, const json& d) {
  std::cout << a.title << " -> " << b.title << "\n";
  for (const Side* side : {&a, &b}) {
    if (const std::string lineage = LineageLong(side->summary); !lineage.empty())
      std::cout << side->label << ": " << lineage << "\n";
    std::string effects;
    for (const model::Augmentation& aug : side->doc.augmentations)
      effects += (effects.empty() ? "" : ", ") + aug.effect;
    std::cout << side->label << " augmentations: " << (effects.empty() ? "none" : effects) << "\n";
  }
  const std::string la = a.label == b.label ? "A: " + a.label : a.label;
  const std::string lb = a.label == b.label ? "B: " + b.label : b.label;
  const json& ja = d["a"];
  const json& jb = d["b"];
  Table overview({"", la, lb, "change"});
  if (a.summary.is_object() || b.summary.is_object()) {
    auto created = [](const Side& s) {
      return s.summary.is_object() ? IsoUtc(s.summary.value("created_utime", int64_t{0})) : "file";
    };
    overview.AddRow({"created (UTC)", created(a), created(b), ""});
    overview.AddRow({"trials", JoinNumbers(ja.value("trials", json())),
                     JoinNumbers(jb.value("trials", json())), ""});
  }
  overview.AddRow({"kind", ja["kind"].get<std::string>(), jb["kind"].get<std::string>(), ""});
  overview.AddRow({"levels V", JoinNumbers(ja["levels_V"]), JoinNumbers(jb["levels_V"]), ""});
  const double fa = NumberIn(a.fit, "fit_percent"), fb = NumberIn(b.fit, "fit_percent");
  const double ra = NumberIn(a.fit, "rmse_mm"), rb = NumberIn(b.fit, "rmse_mm");
  overview.AddRow({"fit %", Cell(fa), Cell(fb), FitPercentChange(fa, fb)});
  overview.AddRow({"RMSE mm", Cell(ra, 3), Cell(rb, 3), MmChange(ra, rb)});
  if (!a.doc.augmentations.empty() || !b.doc.augmentations.empty())
    overview.AddRow(
        {"augmentations", JoinNumbers(ja["augmentations"]), JoinNumbers(jb["augmentations"]), ""});
  overview.Print(std::cout);
  if (a.fit.is_object() && b.fit.is_object() && a.summary.is_object() && b.summary.is_object() &&
      ja.value("trials", json()) != jb.value("trials", json()))
    std::cout << "  (fit figures are on each model's own trials; compare them with care)\n";

  for (const json& local : d["local_models"]) {
    const json& x = local["a"];
    const json& y = local["b"];
    const double level = local["level_V"].is_number() ? local["level_V"].get<double>() : NAN;
    std::cout << "\nlocal model at " << (std::isfinite(level) ? FormatNumber(level, 4) : "?")
              << " V";
    if (x.is_null()) std::cout << " (only in " << b.label << ")";
    if (y.is_null()) std::cout << " (only in " << a.label << ")";
    std::cout << "\n";
    auto value = [](const json& side, const char* key) { return NumberIn(side, key); };
    auto fit_value = [](const json& side, const char* key) {
      return side.is_object() ? NumberIn(side.value("fit", json()), key) : NAN;
    };
    Table table({"", la, lb, "change"});
    const double ga = value(x, "dc_gain_mm_per_V"), gb = value(y, "dc_gain_mm_per_V");
    table.AddRow({"DC gain mm/V", Cell(ga, 5), Cell(gb, 5), PercentChange(ga, gb)});
    const double sa = value(x, "steady_deflection_mm"), sb = value(y, "steady_deflection_mm");
    if (std::isfinite(sa) || std::isfinite(sb))
      table.AddRow({"steady deflection mm", Cell(sa), Cell(sb), MmChange(sa, sb)});
    const double da = value(x, "delay_s"), db = value(y, "delay_s");
    table.AddRow({"dead time s", Cell(da), Cell(db), SecondsChange(da, db)});
    const double ta = value(x, "slowest_time_constant_s"), tb = value(y, "slowest_time_constant_s");
    table.AddRow({"slowest time constant s", Cell(ta), Cell(tb), SecondsChange(ta, tb)});
    auto poles = [](const json& side) {
      if (!side.is_object()) return std::string("-");
      model::TransferFunction tf;
      tf.num = side["num"].get<std::vector<double>>();
      tf.den = side["den"].get<std::vector<double>>();
      return PolesText(tf);
    };
    table.AddRow({"poles 1/s", poles(x), poles(y), ""});
    const double lfa = fit_value(x, "fit_percent"), lfb = fit_value(y, "fit_percent");
    if (std::isfinite(lfa) || std::isfinite(lfb)) {
      const double lra = fit_value(x, "rmse_mm"), lrb = fit_value(y, "rmse_mm");
      table.AddRow({"fit %", Cell(lfa), Cell(lfb), FitPercentChange(lfa, lfb)});
      table.AddRow({"RMSE mm", Cell(lra, 3), Cell(lrb, 3), MmChange(lra, lrb)});
    }
    table.Print(std::cout);
  }

  const json& steps = d["step_responses"];
  if (!steps.empty()) {
    std::cout << "\nstep responses from rest (each model as a whole, over "
              << FormatNumber(steps[0]["horizon_s"].get<double>(), 4) << " s)\n";
    Table table({"step V", la + " final mm", lb + " final mm", "largest difference mm", "at t s",
                 "% of peak"});
    for (const json& s : steps) {
      if (s.value("diverges", false)) {
        table.AddRow(
            {FormatNumber(s["step_V"].get<double>(), 4), "diverges", "diverges", "-", "-", "-"});
        continue;
      }
      table.AddRow({FormatNumber(s["step_V"].get<double>(), 4), Cell(s["final_a_mm"].get<double>()),
                    Cell(s["final_b_mm"].get<double>()),
                    Cell(s["max_abs_difference_mm"].get<double>(), 3),
                    Cell(s["at_t_s"].get<double>()),
                    Cell(NumberIn(s, "max_abs_difference_percent_of_peak"), 3)});
    }
    table.Print(std::cout);
  }
}

void RunDiff(const DiffArgs& args) {
  const Side a = LoadSide(args.actuator, args.a);
  const Side b = LoadSide(args.actuator, args.b);
  const json d = DiffJson(a, b);
  if (args.json) {
    std::cout << d.dump(2) << "\n";
    return;
  }
  PrintDiff(a, b, d);
}

}  // namespace

void AddDiffCommand(CLI::App& models) {
  auto diff = std::make_shared<DiffArgs>();
  CLI::App* diff_cmd = models.add_subcommand(
      "diff",
      "Compare two model versions (or model files): gains, dead times, poles, fit, step "
      "responses");
  diff_cmd->add_option("--actuator", diff->actuator, "Actuator whose versions are compared");
  diff_cmd->add_option("A", diff->a, "Version (3, v3 or active) or model file; the reference")
      ->required();
  diff_cmd->add_option("B", diff->b, "Version or model file compared with A")->required();
  diff_cmd->add_flag("--json", diff->json, "Print the comparison as one JSON document");
  diff_cmd->footer(
      "Local models are matched by level (within 0.5 V or 10 %); changes are B - A. The step\n"
      "responses are both models as a whole, from rest, to a step to each level.\n"
      "Examples:\n  flexid models diff --actuator S1 2 3\n"
      "  flexid models diff --actuator S1 active lab-fit.json\n"
      "  flexid models diff old.json new.json --json");
  diff_cmd->callback([diff] { RunDiff(*diff); });
}

}  // namespace flexid::cli::models
