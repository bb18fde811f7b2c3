// Where the diagnosis says things are (internal to model/diagnose*.cc): the residual by
// operating condition, the spans where an effect acts, whether a fitted effect's size is
// determined, and each finding in plain words.
#pragma once

#include <Eigen/Dense>
#include <span>
#include <string>
#include <vector>

#include "model/core/transfer_function.h"
#include "model/diagnose/diagnose_fit.h"

namespace flexid::model::diagnosis {

std::string Format(const char* fmt, double a);

std::vector<ResidualGroup> GroupResiduals(const Data& data, std::span<const double> r,
                                          std::span<const double> baseline_mm, double transition_s);

// Spans where |delta| is at least `threshold`, joined across gaps shorter than join_s,
// dropping those shorter than 2 samples; at most 12 (the largest by integrated |delta|).
std::vector<TimeSpan> Spans(const Recording& rec, std::span<const double> delta, double threshold,
                            double join_s);

// A named effect needs a determined size: the 95 % interval of how much of it there is
// excludes none. The size is a function of the effect's parameters: its fraction, loss,
// width or threshold; 1 - slope or 1 - ratio; a sensor drift's displacement at the middle
// or at the end of the recording (its linear and warm-up parts are correlated, neither
// need be determined alone). The interval comes from the fit's covariance (the last
// parameters are the effect's) by the delta method. `text` says what was found.
// Used with a trusted model, whose effect fits hold the baseline: with an identified
// baseline refitted with the effect, a dozen raw polynomial coefficients share the
// covariance and its Wald intervals mean little (a saturation's 1 - slope came out
// 0.83 +- 5.6e4). There the likelihood ratio against the baseline refitted without the
// effect is the profile test of size = none, at a stricter level than 95 %.
bool SizeDetermined(const Effect& effect, const Eigen::MatrixXd& covariance,
                    const Eigen::MatrixXd& null_space, double duration_s, double top_V,
                    std::string* text);

// Where an effect acts: where what it adds (delta) reaches half the noise and 0.3 of its
// peak; for a relaxation, which acts during holds, the holds where it does.
std::vector<TimeSpan> WhereItActs(const Data& data, std::span<const double> delta, EffectKind kind);

std::string Explain(const Effect& e, const Data& data, std::span<const double> delta,
                    double before_mm, double after_mm, const std::string& model_words);

// "1.23 mm".
std::string Mm(double v);

// The identified model read against the physics chain (Eqs. 11-13): a step response that
// rises above its final value and falls back is back-relaxation the free fit absorbed.
std::vector<Absorbed> ReadAgainstPhysics(const TsModel& model, double noise_mm);

}  // namespace flexid::model::diagnosis
