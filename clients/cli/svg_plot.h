// A small SVG line-chart writer for flexid's reports and plots: named series (optionally
// dashed, optionally drawn as a zero-order hold), shaded x-spans (held-out blocks, located
// effects), a legend, axes with "nice" 1-2-5 ticks and a grid.
//
// The output is a standalone SVG document (it also works inline in HTML5), with no ids,
// scripts or external references, and it is deterministic: the same chart always gives the
// same bytes. Every text and attribute value is escaped. Non-finite points are skipped
// and break the line. Long series are decimated to about kMaxPointsPerSeries points by
// keeping the minimum and maximum of each x bucket, so single-sample spikes stay visible.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace flexid::cli {

// Upper bound (approximately; gaps add a few) on the points drawn per series.
inline constexpr size_t kMaxPointsPerSeries = 2000;

struct Series {
  std::string name;  // legend text
  std::vector<double> x;
  std::vector<double> y;           // same length as x (extra values of the longer one are ignored)
  std::string colour = "#1f77b4";  // any SVG colour
  bool dashed = false;
  bool step = false;  // zero-order hold: y[i] holds from x[i] until x[i + 1]
};

// A shaded vertical band from x_start to x_end (clipped to the axis range).
struct Span {
  double x_start = 0.0;
  double x_end = 0.0;
  std::string colour = "#e0e0e0";
  double opacity = 1.0;  // fill opacity in [0, 1]; below 1, overlapping spans both show
  std::string label;     // legend text; spans with the same label get one legend entry
};

struct Chart {
  std::string title;
  std::string x_label;  // with the unit, e.g. "time (s)"
  std::string y_label;  // with the unit, e.g. "deflection (mm)"
  std::vector<Series> series;
  std::vector<Span> spans;
};

// Where a chart's parts go on a canvas of width x height pixels (origin top left, y down):
// the plot area, the axis ranges and ticks, and the legend. RenderSvg and RenderPng
// (png_plot.h) draw the same layout, so both formats look alike.
struct LegendEntry {
  std::string label;
  std::string colour;
  bool is_span = false;  // a shaded box (span) rather than a line (series)
  bool dashed = false;
  double opacity = 1.0;
  double x_px = 0.0;  // left end of the sample
  int row = 0;        // legend row, from 0
};

struct ChartLayout {
  double width = 0.0, height = 0.0;
  double left = 0.0, right = 0.0, top = 0.0, bottom = 0.0;      // plot area, px
  double x_low = 0.0, x_high = 1.0, y_low = 0.0, y_high = 1.0;  // axis ranges, data units
  std::vector<double> x_ticks, y_ticks;                         // data units
  std::vector<LegendEntry> legend;
  double XPx(double x) const { return left + (x - x_low) / (x_high - x_low) * (right - left); }
  double YPx(double y) const { return bottom - (y - y_low) / (y_high - y_low) * (bottom - top); }
  // Baseline of the legend texts of row `row`.
  double LegendRowPx(int row) const;
};

// The layout RenderSvg uses (sizes below 200 px are raised to 200).
ChartLayout LayoutChart(const Chart& chart, int width_px, int height_px);

// A point in pixels.
struct PointPx {
  double x = 0.0, y = 0.0;
};

// The lines a series is drawn as, in pixels: the hold points of a step series inserted,
// decimated with DecimateMinMax, broken where a point is not finite. A line may hold a
// single point.
std::vector<std::vector<PointPx>> SeriesPolylines(const Series& series, const ChartLayout& layout);

// The chart as an SVG document of width_px x height_px (each at least 200; smaller values
// are raised to 200). The x axis spans the finite data, with the NiceTicks inside it; the
// y axis runs from the first to the last NiceTicks value around the finite data. One
// <path> per series; the legend uses <line> and <rect>.
std::string RenderSvg(const Chart& chart, int width_px, int height_px);

// Tick values at a 1, 2 or 5 times 10^k step, about target_count of them, from a multiple
// of the step at or below `low` to one at or above `high`. An empty or non-finite range
// is widened (low == high gives a range around the value, non-finite gives [0, 1]).
std::vector<double> NiceTicks(double low, double high, int target_count = 6);

// Indices (ascending) of the points kept when a series of x non-decreasing is drawn with
// at most about max_points points: if it has more finite points than that, the x range is
// cut into max_points / 2 buckets and each run of consecutive finite points in one bucket
// keeps its minimum and maximum y. A non-finite point (x or y) that follows a finite one
// is kept as a gap marker. With fewer finite points, every index is returned.
std::vector<size_t> DecimateMinMax(std::span<const double> x, std::span<const double> y,
                                   size_t max_points = kMaxPointsPerSeries);

// Escapes & < > " ' for XML and HTML text and attribute values; control characters other
// than tab, newline and carriage return (invalid in XML) become spaces.
std::string EscapeXml(std::string_view text);

}  // namespace flexid::cli
