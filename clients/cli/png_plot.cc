// Draws svg_plot.h's charts with cairo into PNG images (png_plot.h). Every position comes
// from LayoutChart and SeriesPolylines, shared with RenderSvg; only the drawing differs.
// Grid lines and the frame are snapped to pixel centres so that they stay crisp.
#include "clients/cli/png_plot.h"

#include <cairo.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string_view>

#include "clients/cli/format.h"

namespace flexid::cli {
namespace {

constexpr double kFontPx = 12.0;
constexpr double kTitleFontPx = 14.0;

struct SurfaceDeleter {
  void operator()(cairo_surface_t* surface) const { cairo_surface_destroy(surface); }
};
struct ContextDeleter {
  void operator()(cairo_t* cr) const { cairo_destroy(cr); }
};
using Surface = std::unique_ptr<cairo_surface_t, SurfaceDeleter>;
using Context = std::unique_ptr<cairo_t, ContextDeleter>;

void SetColour(cairo_t* cr, uint32_t rgb, double alpha = 1.0) {
  cairo_set_source_rgba(cr, ((rgb >> 16) & 0xff) / 255.0, ((rgb >> 8) & 0xff) / 255.0,
                        (rgb & 0xff) / 255.0,
                        std::isfinite(alpha) ? std::clamp(alpha, 0.0, 1.0) : 1.0);
}

void SetColour(cairo_t* cr, const std::string& colour, double alpha = 1.0) {
  SetColour(cr, ParseColour(colour), alpha);
}

// The centre of the pixel a 1 px line at `value` should cover.
double Crisp(double value) { return std::floor(value) + 0.5; }

enum class Anchor { kStart, kMiddle, kEnd };

void Text(cairo_t* cr, double x, double y, const std::string& text, Anchor anchor = Anchor::kStart,
          double size_px = kFontPx, bool bold = false) {
  if (text.empty()) return;
  cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL,
                         bold ? CAIRO_FONT_WEIGHT_BOLD : CAIRO_FONT_WEIGHT_NORMAL);
  cairo_set_font_size(cr, size_px);
  cairo_text_extents_t extents;
  cairo_text_extents(cr, text.c_str(), &extents);
  if (anchor == Anchor::kMiddle) x -= extents.x_advance / 2.0;
  if (anchor == Anchor::kEnd) x -= extents.x_advance;
  cairo_move_to(cr, x, y);
  cairo_show_text(cr, text.c_str());
  cairo_new_path(cr);
}

void Dashes(cairo_t* cr, bool dashed) {
  static const double kPattern[] = {6.0, 4.0};
  cairo_set_dash(cr, kPattern, dashed ? 2 : 0, 0.0);
}

void DrawChart(cairo_t* cr, const Chart& chart, const ChartLayout& layout) {
  const double left = layout.left, right = layout.right, top = layout.top, bottom = layout.bottom;
  SetColour(cr, 0xffffff);
  cairo_rectangle(cr, 0.0, 0.0, layout.width, layout.height);
  cairo_fill(cr);

  SetColour(cr, 0x222222);
  Text(cr, layout.width / 2.0, 20.0, chart.title, Anchor::kMiddle, kTitleFontPx, true);

  // Shaded spans, under everything else.
  for (const auto& span : chart.spans) {
    const double a = std::clamp(std::min(span.x_start, span.x_end), layout.x_low, layout.x_high);
    const double b = std::clamp(std::max(span.x_start, span.x_end), layout.x_low, layout.x_high);
    if (!std::isfinite(a) || !std::isfinite(b) || b <= a) continue;
    SetColour(cr, span.colour, span.opacity);
    cairo_rectangle(cr, layout.XPx(a), top, layout.XPx(b) - layout.XPx(a), bottom - top);
    cairo_fill(cr);
  }

  // Grid and tick labels.
  cairo_set_line_width(cr, 1.0);
  Dashes(cr, false);
  for (const double t : layout.x_ticks) {
    const double x = Crisp(layout.XPx(t));
    SetColour(cr, 0xe2e2e2);
    cairo_move_to(cr, x, top);
    cairo_line_to(cr, x, bottom);
    cairo_stroke(cr);
    SetColour(cr, 0x222222);
    Text(cr, layout.XPx(t), bottom + 15.0, FormatNumber(t), Anchor::kMiddle);
  }
  for (const double t : layout.y_ticks) {
    const double y = Crisp(layout.YPx(t));
    SetColour(cr, 0xe2e2e2);
    cairo_move_to(cr, left, y);
    cairo_line_to(cr, right, y);
    cairo_stroke(cr);
    SetColour(cr, 0x222222);
    Text(cr, left - 6.0, layout.YPx(t) + 4.0, FormatNumber(t), Anchor::kEnd);
  }
  SetColour(cr, 0x444444);
  cairo_rectangle(cr, Crisp(left), Crisp(top), std::round(right - left), std::round(bottom - top));
  cairo_stroke(cr);
  SetColour(cr, 0x222222);
  Text(cr, (left + right) / 2.0, bottom + 32.0, chart.x_label, Anchor::kMiddle);
  if (!chart.y_label.empty()) {
    cairo_save(cr);
    cairo_translate(cr, 16.0, (top + bottom) / 2.0);
    cairo_rotate(cr, -M_PI / 2.0);
    Text(cr, 0.0, 0.0, chart.y_label, Anchor::kMiddle);
    cairo_restore(cr);
  }

  // Series, clipped to the plot area (a line width beyond it, as the SVG shows them).
  cairo_save(cr);
  cairo_rectangle(cr, left - 2.0, top - 2.0, right - left + 4.0, bottom - top + 4.0);
  cairo_clip(cr);
  cairo_set_line_width(cr, 1.5);
  cairo_set_line_join(cr, CAIRO_LINE_JOIN_ROUND);
  cairo_set_line_cap(cr, CAIRO_LINE_CAP_ROUND);
  for (const auto& series : chart.series) {
    SetColour(cr, series.colour);
    Dashes(cr, series.dashed);
    for (const auto& line : SeriesPolylines(series, layout)) {
      cairo_move_to(cr, line.front().x, line.front().y);
      for (size_t i = 1; i < line.size(); ++i) cairo_line_to(cr, line[i].x, line[i].y);
      if (line.size() == 1) cairo_line_to(cr, line.front().x, line.front().y);  // a dot
    }
    cairo_stroke(cr);
  }
  cairo_restore(cr);
  Dashes(cr, false);

  // Legend rows under the x label.
  for (const auto& entry : layout.legend) {
    const double y = layout.LegendRowPx(entry.row);
    if (entry.is_span) {
      SetColour(cr, entry.colour, entry.opacity);
      cairo_rectangle(cr, entry.x_px, y - 9.0, 24.0, 11.0);
      cairo_fill(cr);
      SetColour(cr, 0x999999);
      cairo_set_line_width(cr, 1.0);
      cairo_rectangle(cr, Crisp(entry.x_px), Crisp(y - 9.0), 24.0, 11.0);
      cairo_stroke(cr);
    } else {
      SetColour(cr, entry.colour);
      cairo_set_line_width(cr, 2.0);
      Dashes(cr, entry.dashed);
      cairo_move_to(cr, entry.x_px, y - 4.0);
      cairo_line_to(cr, entry.x_px + 24.0, y - 4.0);
      cairo_stroke(cr);
      Dashes(cr, false);
    }
    SetColour(cr, 0x222222);
    Text(cr, entry.x_px + 30.0, y, entry.label);
  }
}

cairo_status_t AppendToString(void* closure, const unsigned char* data, unsigned int length) {
  static_cast<std::string*>(closure)->append(reinterpret_cast<const char*>(data), length);
  return CAIRO_STATUS_SUCCESS;
}

int HexDigit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

}  // namespace

uint32_t ParseColour(const std::string& colour) {
  if (!colour.empty() && colour[0] == '#' && (colour.size() == 4 || colour.size() == 7)) {
    uint32_t rgb = 0;
    const bool short_form = colour.size() == 4;
    for (size_t i = 1; i < colour.size(); ++i) {
      const int digit = HexDigit(colour[i]);
      if (digit < 0) return 0x000000;
      rgb = short_form ? (rgb << 8) | static_cast<uint32_t>(digit * 17)
                       : (rgb << 4) | static_cast<uint32_t>(digit);
    }
    return rgb;
  }
  struct Named {
    std::string_view name;
    uint32_t rgb;
  };
  static constexpr Named kNames[] = {{"black", 0x000000}, {"white", 0xffffff}, {"red", 0xff0000},
                                     {"green", 0x008000}, {"blue", 0x0000ff},  {"grey", 0x808080},
                                     {"gray", 0x808080},  {"orange", 0xffa500}};
  for (const Named& n : kNames)
    if (colour == n.name) return n.rgb;
  return 0x000000;
}

std::string RenderPng(const std::vector<Chart>& charts, int width_px, int chart_height_px) {
  const int width = std::max(width_px, 200);
  const int chart_height = std::max(chart_height_px, 200);
  const int height = chart_height * std::max<int>(1, static_cast<int>(charts.size()));
  Surface surface(cairo_image_surface_create(CAIRO_FORMAT_ARGB32, width, height));
  if (cairo_surface_status(surface.get()) != CAIRO_STATUS_SUCCESS)
    throw std::runtime_error(
        std::string("cannot create a ") + std::to_string(width) + "x" + std::to_string(height) +
        " image: " + cairo_status_to_string(cairo_surface_status(surface.get())));
  Context cr(cairo_create(surface.get()));
  cairo_font_options_t* options = cairo_font_options_create();
  cairo_font_options_set_antialias(options, CAIRO_ANTIALIAS_GRAY);
  cairo_font_options_set_hint_style(options, CAIRO_HINT_STYLE_SLIGHT);
  cairo_set_font_options(cr.get(), options);
  cairo_font_options_destroy(options);
  cairo_set_source_rgb(cr.get(), 1.0, 1.0, 1.0);
  cairo_paint(cr.get());
  for (size_t i = 0; i < charts.size(); ++i) {
    cairo_save(cr.get());
    cairo_translate(cr.get(), 0.0, static_cast<double>(i) * chart_height);
    DrawChart(cr.get(), charts[i], LayoutChart(charts[i], width, chart_height));
    cairo_restore(cr.get());
  }
  if (cairo_status(cr.get()) != CAIRO_STATUS_SUCCESS)
    throw std::runtime_error(std::string("cannot draw the chart: ") +
                             cairo_status_to_string(cairo_status(cr.get())));
  cairo_surface_flush(surface.get());
  std::string png;
  const cairo_status_t status =
      cairo_surface_write_to_png_stream(surface.get(), AppendToString, &png);
  if (status != CAIRO_STATUS_SUCCESS)
    throw std::runtime_error(std::string("cannot encode the PNG image: ") +
                             cairo_status_to_string(status));
  return png;
}

PngImage ReadPng(const std::string& path) {
  Surface surface(cairo_image_surface_create_from_png(path.c_str()));
  if (cairo_surface_status(surface.get()) != CAIRO_STATUS_SUCCESS)
    throw std::runtime_error(path + ": not a readable PNG image (" +
                             cairo_status_to_string(cairo_surface_status(surface.get())) + ")");
  cairo_surface_flush(surface.get());
  const cairo_format_t format = cairo_image_surface_get_format(surface.get());
  PngImage image;
  image.width = cairo_image_surface_get_width(surface.get());
  image.height = cairo_image_surface_get_height(surface.get());
  const int stride = cairo_image_surface_get_stride(surface.get());
  const unsigned char* data = cairo_image_surface_get_data(surface.get());
  image.argb.resize(static_cast<size_t>(image.width) * static_cast<size_t>(image.height));
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      uint32_t pixel = 0;
      if (format == CAIRO_FORMAT_ARGB32 || format == CAIRO_FORMAT_RGB24) {
        std::memcpy(&pixel, data + static_cast<ptrdiff_t>(y) * stride + 4 * x, sizeof pixel);
        if (format == CAIRO_FORMAT_RGB24) pixel |= 0xff000000u;
      } else if (format == CAIRO_FORMAT_A8) {
        pixel = static_cast<uint32_t>(data[static_cast<ptrdiff_t>(y) * stride + x]) << 24;
      }
      image.argb[static_cast<size_t>(y) * static_cast<size_t>(image.width) +
                 static_cast<size_t>(x)] = pixel;
    }
  }
  return image;
}

}  // namespace flexid::cli
