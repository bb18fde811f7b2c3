// The report of `flexid diagnose` as one self-contained HTML5 page for a lab engineer:
// inline CSS and SVG charts (clients/cli/svg_plot.h), no scripts, no external links or
// fonts, so it can be mailed or archived as a single file.
//
// Sections, top to bottom:
//  - the verdict and each finding's explanation; the baseline's figures (fit %, training
//    and held-out RMSE, noise estimate) and where the baseline came from;
//  - measured deflection with the baseline and augmented predictions over time (held-out
//    blocks and the verdict's spans shaded), the applied voltage below it (step style);
//  - the residual before (measured - baseline) and after (measured - augmented);
//  - the findings' parameters (value +- 95 % half-width) and held-out RMSE before -> after;
//  - every candidate tried with its figures and why it was or was not claimed;
//  - the residual broken down by operating condition, the baseline residual's whiteness
//    and input cross-correlation tests, what a free fit absorbed, and the notes.
// Every string taken from the recording or the diagnosis is HTML-escaped.
#pragma once

#include <string>

#include "model/diagnose.h"
#include "model/recording.h"

namespace flexid::cli {

// The page; `title` heads it (escaped). Series shorter than the recording are drawn over
// the samples they cover.
std::string DiagnosisReportHtml(const model::Recording& recording,
                                const model::Diagnosis& diagnosis, const std::string& title);

}  // namespace flexid::cli
