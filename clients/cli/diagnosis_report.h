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
//
// The pieces below build other pages in the same style (`flexid report`).
#pragma once

#include <string>
#include <vector>

#include "model/core/recording.h"
#include "model/diagnose/diagnose.h"
#include "model/identify/identify.h"

namespace flexid::cli {

// "<!DOCTYPE html> ... <body><h1>title</h1>": the head with the inline CSS, title escaped.
std::string HtmlPageStart(const std::string& title);

// The version line and the closing tags.
std::string HtmlPageEnd();

// One line: the recording's source, samples, duration and voltage range.
std::string RecordingSummaryHtml(const model::Recording& recording);

// The diagnosis sections listed above (verdict to notes), with headings at heading_level
// (2: <h2>; 3 nests them under a page's own <h2>). `recordings`: what was diagnosed, in the
// order given to model::Diagnose (one chart set each).
std::string DiagnosisSectionsHtml(const std::vector<model::Recording>& recordings,
                                  const model::Diagnosis& diagnosis, int heading_level = 2);

// The whiteness and input cross-correlation tests of a fit as a table: statistic,
// threshold and pass or fail ("not computed" when the fit has none).
std::string ResidualTestsTableHtml(const model::FitFigures& fit);

// The page; `title` heads it (escaped). Series shorter than the recording are drawn over
// the samples they cover.
std::string DiagnosisReportHtml(const std::vector<model::Recording>& recordings,
                                const model::Diagnosis& diagnosis, const std::string& title);

}  // namespace flexid::cli
