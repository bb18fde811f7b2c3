#include "clients/cli/svg_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "clients/cli/format.h"

namespace flexid::cli {
namespace {

constexpr int kMinSizePx = 200;
constexpr double kLegendRowPx = 18.0;
constexpr double kCharWidthPx = 6.5;  // rough width of a 12 px sans-serif character

bool IsFinitePoint(double x, double y) { return std::isfinite(x) && std::isfinite(y); }

// Pixel coordinates with 0.1 px resolution.
std::string Px(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.1f", value);
  return buffer;
}

std::string Opacity(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.2f",
                std::isfinite(value) ? std::clamp(value, 0.0, 1.0) : 1.0);
  return buffer;
}

struct Range {
  double low = std::numeric_limits<double>::infinity();
  double high = -std::numeric_limits<double>::infinity();
  void Add(double value) {
    low = std::min(low, value);
    high = std::max(high, value);
  }
  bool Empty() const { return low > high; }
};

// The points a series is drawn through: as given, or with the hold points of a
// zero-order hold inserted, (x[i], y[i]), (x[i + 1], y[i]), (x[i + 1], y[i + 1]), ...
void DrawnPoints(const Series& series, std::vector<double>* x, std::vector<double>* y) {
  const size_t n = std::min(series.x.size(), series.y.size());
  x->clear();
  y->clear();
  for (size_t i = 0; i < n; ++i) {
    x->push_back(series.x[i]);
    y->push_back(series.y[i]);
    if (series.step && i + 1 < n) {
      x->push_back(series.x[i + 1]);
      y->push_back(series.y[i]);
    }
  }
}

std::vector<LegendEntry> LegendEntries(const Chart& chart) {
  std::vector<LegendEntry> entries;
  for (const auto& series : chart.series)
    if (!series.name.empty()) entries.push_back({series.name, series.colour, false, series.dashed});
  for (const auto& span : chart.spans) {
    if (span.label.empty()) continue;
    const bool seen = std::any_of(entries.begin(), entries.end(), [&](const LegendEntry& e) {
      return e.is_span && e.label == span.label;
    });
    if (!seen) entries.push_back({span.label, span.colour, true, false, span.opacity});
  }
  return entries;
}

// Places the entries left to right in rows of at most `width_px`; returns the row count.
int LayoutLegend(std::vector<LegendEntry>* entries, double left_px, double width_px) {
  int row = 0;
  double x = 0.0;
  for (auto& entry : *entries) {
    const double entry_px = 30.0 + kCharWidthPx * static_cast<double>(entry.label.size()) + 16.0;
    if (x > 0.0 && x + entry_px > width_px) {
      ++row;
      x = 0.0;
    }
    entry.x_px = left_px + x;
    entry.row = row;
    x += entry_px;
  }
  return entries->empty() ? 0 : row + 1;
}

}  // namespace

std::string EscapeXml(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&#39;";
        break;
      case '\t':
      case '\n':
      case '\r':
        out += c;
        break;
      default:
        out += (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) ? ' ' : c;
    }
  }
  return out;
}

std::vector<double> NiceTicks(double low, double high, int target_count) {
  if (!std::isfinite(low) || !std::isfinite(high)) {
    low = 0.0;
    high = 1.0;
  }
  if (low > high) std::swap(low, high);
  if (low == high) {
    const double half = low == 0.0 ? 1.0 : 0.1 * std::abs(low);
    low -= half;
    high += half;
  }
  target_count = std::max(target_count, 2);
  // Step: the smallest of 1, 2, 5, 10 times 10^k at or above range / target_count.
  const double raw_step = (high - low) / target_count;
  if (!std::isfinite(raw_step) || raw_step <= 0.0) return {low, high};
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw_step)));
  double step = 10.0 * magnitude;
  for (const double mantissa : {1.0, 2.0, 5.0}) {
    if (mantissa * magnitude >= raw_step) {
      step = mantissa * magnitude;
      break;
    }
  }
  // Ticks as integer multiples of the step, so that they print cleanly.
  double first = std::floor(low / step);
  double last = std::ceil(high / step);
  if (first * step > low) first -= 1.0;  // rounding of the division: still cover the range
  if (last * step < high) last += 1.0;
  // Beyond 2^53 (or at the precision limit of low and high) the step is not representable.
  if (!(last - first >= 1.0 && last - first <= 1000.0)) return {low, high};
  std::vector<double> ticks;
  for (int i = 0; i <= static_cast<int>(last - first); ++i) {
    const double k = first + i;
    ticks.push_back(k == 0.0 ? 0.0 : k * step);
  }
  return ticks;
}

std::vector<size_t> DecimateMinMax(std::span<const double> x, std::span<const double> y,
                                   size_t max_points) {
  const size_t n = std::min(x.size(), y.size());
  max_points = std::max<size_t>(max_points, 2);
  Range x_range;
  size_t finite = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!IsFinitePoint(x[i], y[i])) continue;
    ++finite;
    x_range.Add(x[i]);
  }
  std::vector<size_t> kept;
  if (finite <= max_points) {
    for (size_t i = 0; i < n; ++i) kept.push_back(i);
    return kept;
  }

  const size_t buckets = max_points / 2;
  const double width = x_range.high - x_range.low;
  auto bucket_of = [&](double value) -> size_t {
    if (width <= 0.0) return 0;
    const double b = std::floor((value - x_range.low) / width * static_cast<double>(buckets));
    return std::min(buckets - 1, static_cast<size_t>(std::max(b, 0.0)));
  };

  // The current group: consecutive finite points in one bucket, its min and max y.
  bool in_group = false;
  size_t group_bucket = 0, lowest = 0, highest = 0;
  auto flush = [&] {
    if (!in_group) return;
    kept.push_back(std::min(lowest, highest));
    if (lowest != highest) kept.push_back(std::max(lowest, highest));
    in_group = false;
  };
  for (size_t i = 0; i < n; ++i) {
    if (!IsFinitePoint(x[i], y[i])) {
      flush();
      if (i > 0 && IsFinitePoint(x[i - 1], y[i - 1])) kept.push_back(i);  // gap marker
      continue;
    }
    const size_t b = bucket_of(x[i]);
    if (in_group && b == group_bucket) {
      if (y[i] < y[lowest]) lowest = i;
      if (y[i] > y[highest]) highest = i;
      continue;
    }
    flush();
    in_group = true;
    group_bucket = b;
    lowest = highest = i;
  }
  flush();
  return kept;
}

double ChartLayout::LegendRowPx(int row) const { return bottom + 50.0 + kLegendRowPx * row; }

ChartLayout LayoutChart(const Chart& chart, int width_px, int height_px) {
  ChartLayout layout;
  layout.width = std::max(width_px, kMinSizePx);
  layout.height = std::max(height_px, kMinSizePx);

  // Title on top, tick labels and the y label left, tick labels, the x label and the
  // legend below the plot area.
  layout.left = 72.0;
  layout.right = layout.width - 16.0;
  layout.top = chart.title.empty() ? 12.0 : 32.0;
  layout.legend = LegendEntries(chart);
  const int legend_rows = LayoutLegend(&layout.legend, layout.left, layout.right - layout.left);
  layout.bottom = std::max(layout.top + 40.0, layout.height - 46.0 - kLegendRowPx * legend_rows);

  // Axis ranges. y: from the first to the last tick around the finite data. x (usually
  // time): the data range itself, with the ticks that fall inside it.
  Range x_data, y_data;
  for (const auto& series : chart.series) {
    const size_t n = std::min(series.x.size(), series.y.size());
    for (size_t i = 0; i < n; ++i) {
      if (!IsFinitePoint(series.x[i], series.y[i])) continue;
      x_data.Add(series.x[i]);
      y_data.Add(series.y[i]);
    }
  }
  if (x_data.Empty()) x_data = {0.0, 1.0};
  if (y_data.Empty()) y_data = {0.0, 1.0};
  layout.x_ticks = NiceTicks(x_data.low, x_data.high,
                             std::max(2, static_cast<int>((layout.right - layout.left) / 110.0)));
  if (x_data.low == x_data.high) x_data = {layout.x_ticks.front(), layout.x_ticks.back()};
  const double x_tolerance = 1e-9 * (x_data.high - x_data.low);
  std::erase_if(layout.x_ticks, [&](double t) {
    return t < x_data.low - x_tolerance || t > x_data.high + x_tolerance;
  });
  layout.y_ticks = NiceTicks(y_data.low, y_data.high,
                             std::max(4, static_cast<int>((layout.bottom - layout.top) / 55.0)));
  layout.x_low = x_data.low;
  layout.x_high = x_data.high;
  layout.y_low = layout.y_ticks.front();
  layout.y_high = layout.y_ticks.back();
  return layout;
}

std::vector<std::vector<PointPx>> SeriesPolylines(const Series& series, const ChartLayout& layout) {
  std::vector<double> xs, ys;
  DrawnPoints(series, &xs, &ys);
  std::vector<std::vector<PointPx>> lines;
  bool pen_down = false;
  for (const size_t i : DecimateMinMax(xs, ys)) {
    if (!IsFinitePoint(xs[i], ys[i])) {
      pen_down = false;
      continue;
    }
    if (!pen_down) lines.emplace_back();
    lines.back().push_back({layout.XPx(xs[i]), layout.YPx(ys[i])});
    pen_down = true;
  }
  return lines;
}

std::string RenderSvg(const Chart& chart, int width_px, int height_px) {
  const ChartLayout layout = LayoutChart(chart, width_px, height_px);
  const double width = layout.width, height = layout.height;
  const double left = layout.left, right = layout.right, top = layout.top, bottom = layout.bottom;
  const double x_low = layout.x_low, x_high = layout.x_high;
  const std::vector<double>& x_ticks = layout.x_ticks;
  const std::vector<double>& y_ticks = layout.y_ticks;
  auto to_px_x = [&](double v) { return layout.XPx(v); };
  auto to_px_y = [&](double v) { return layout.YPx(v); };

  std::string svg;
  svg += "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + Px(width) + "\" height=\"" +
         Px(height) + "\" viewBox=\"0 0 " + Px(width) + " " + Px(height) +
         "\" font-family=\"sans-serif\" font-size=\"12\">\n";
  svg += "<rect x=\"0\" y=\"0\" width=\"" + Px(width) + "\" height=\"" + Px(height) +
         "\" fill=\"#ffffff\"/>\n";
  if (!chart.title.empty())
    svg += "<text x=\"" + Px(width / 2) + "\" y=\"20.0\" text-anchor=\"middle\" " +
           "font-size=\"14\" font-weight=\"bold\">" + EscapeXml(chart.title) + "</text>\n";

  // Shaded spans, under everything else.
  for (const auto& span : chart.spans) {
    const double a = std::clamp(std::min(span.x_start, span.x_end), x_low, x_high);
    const double b = std::clamp(std::max(span.x_start, span.x_end), x_low, x_high);
    if (!std::isfinite(a) || !std::isfinite(b) || b <= a) continue;
    svg += "<rect x=\"" + Px(to_px_x(a)) + "\" y=\"" + Px(top) + "\" width=\"" +
           Px(to_px_x(b) - to_px_x(a)) + "\" height=\"" + Px(bottom - top) + "\" fill=\"" +
           EscapeXml(span.colour) + "\" fill-opacity=\"" + Opacity(span.opacity) + "\"/>\n";
  }

  // Grid and tick labels.
  for (const double t : x_ticks) {
    const std::string x = Px(to_px_x(t));
    svg += "<line x1=\"" + x + "\" y1=\"" + Px(top) + "\" x2=\"" + x + "\" y2=\"" + Px(bottom) +
           "\" stroke=\"#d8d8d8\" stroke-width=\"0.6\"/>\n";
    svg += "<text x=\"" + x + "\" y=\"" + Px(bottom + 15.0) + "\" text-anchor=\"middle\">" +
           EscapeXml(FormatNumber(t)) + "</text>\n";
  }
  for (const double t : y_ticks) {
    const std::string y = Px(to_px_y(t));
    svg += "<line x1=\"" + Px(left) + "\" y1=\"" + y + "\" x2=\"" + Px(right) + "\" y2=\"" + y +
           "\" stroke=\"#d8d8d8\" stroke-width=\"0.6\"/>\n";
    svg += "<text x=\"" + Px(left - 6.0) + "\" y=\"" + Px(to_px_y(t) + 4.0) +
           "\" text-anchor=\"end\">" + EscapeXml(FormatNumber(t)) + "</text>\n";
  }
  svg += "<rect x=\"" + Px(left) + "\" y=\"" + Px(top) + "\" width=\"" + Px(right - left) +
         "\" height=\"" + Px(bottom - top) + "\" fill=\"none\" stroke=\"#444444\"/>\n";
  if (!chart.x_label.empty())
    svg += "<text x=\"" + Px((left + right) / 2) + "\" y=\"" + Px(bottom + 32.0) +
           "\" text-anchor=\"middle\">" + EscapeXml(chart.x_label) + "</text>\n";
  if (!chart.y_label.empty()) {
    const std::string x = "16.0", y = Px((top + bottom) / 2);
    svg += "<text x=\"" + x + "\" y=\"" + y + "\" text-anchor=\"middle\" transform=\"rotate(-90 " +
           x + " " + y + ")\">" + EscapeXml(chart.y_label) + "</text>\n";
  }

  // Series: one path each; a non-finite point lifts the pen.
  for (const auto& series : chart.series) {
    std::string d;
    for (const auto& line : SeriesPolylines(series, layout)) {
      for (size_t i = 0; i < line.size(); ++i) {
        d += i > 0 ? "L" : (d.empty() ? "M" : " M");
        d += Px(line[i].x) + " " + Px(line[i].y);
      }
    }
    svg += "<path d=\"" + d + "\" fill=\"none\" stroke=\"" + EscapeXml(series.colour) +
           "\" stroke-width=\"1.3\" stroke-linejoin=\"round\"" +
           (series.dashed ? " stroke-dasharray=\"6 4\"" : "") + "/>\n";
  }

  // Legend rows under the x label.
  for (const auto& entry : layout.legend) {
    const double y = layout.LegendRowPx(entry.row);
    if (entry.is_span) {
      svg += "<rect x=\"" + Px(entry.x_px) + "\" y=\"" + Px(y - 9.0) + "\" width=\"24.0\" " +
             "height=\"11.0\" fill=\"" + EscapeXml(entry.colour) + "\" fill-opacity=\"" +
             Opacity(entry.opacity) + "\" stroke=\"#999999\"/>\n";
    } else {
      svg += "<line x1=\"" + Px(entry.x_px) + "\" y1=\"" + Px(y - 4.0) + "\" x2=\"" +
             Px(entry.x_px + 24.0) + "\" y2=\"" + Px(y - 4.0) + "\" stroke=\"" +
             EscapeXml(entry.colour) + "\" stroke-width=\"2\"" +
             (entry.dashed ? " stroke-dasharray=\"6 4\"" : "") + "/>\n";
    }
    svg += "<text x=\"" + Px(entry.x_px + 30.0) + "\" y=\"" + Px(y) + "\">" +
           EscapeXml(entry.label) + "</text>\n";
  }
  svg += "</svg>";
  return svg;
}

}  // namespace flexid::cli
