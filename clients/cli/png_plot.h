// Charts as PNG images: the Chart of svg_plot.h drawn with cairo on the same layout
// (LayoutChart) as RenderSvg, so a PNG and an SVG of one chart look alike: white
// background, grid, ticks and labels (cairo's toy text API, sans-serif), series in their
// colours (dashes included), shaded spans and the legend.
//
// cairo stays inside png_plot.cc; this header needs no cairo headers.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "clients/cli/svg_plot.h"

namespace flexid::cli {

// The charts stacked top to bottom, each width_px x chart_height_px (each at least 200;
// smaller values are raised to 200), as the bytes of one PNG file (32-bit RGBA). Throws
// std::runtime_error if cairo fails (e.g. out of memory for a huge image).
std::string RenderPng(const std::vector<Chart>& charts, int width_px, int chart_height_px);

// A decoded image, row-major from the top left; each pixel 0xAARRGGBB (premultiplied alpha,
// as cairo keeps it; the charts are opaque).
struct PngImage {
  int width = 0;
  int height = 0;
  std::vector<uint32_t> argb;
  uint32_t Pixel(int x, int y) const {
    return argb[static_cast<size_t>(y) * static_cast<size_t>(width) + static_cast<size_t>(x)];
  }
};

// Decodes a PNG file with cairo. Throws std::runtime_error "PATH: not a readable PNG image".
PngImage ReadPng(const std::string& path);

// An SVG colour as 0xRRGGBB: "#rgb", "#rrggbb" and the basic names (black, white, red,
// green, blue, grey/gray, orange); anything else gives black.
uint32_t ParseColour(const std::string& colour);

}  // namespace flexid::cli
