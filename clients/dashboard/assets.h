// The dashboard's web assets (clients/dashboard/web/), compiled into the binary by
// embed_assets.cmake so that the server needs no files and no network at run time.
#pragma once

#include <cstddef>
#include <string_view>
#include <vector>

namespace flexid::dashboard {

struct Asset {
  std::string_view path;          // URL path, e.g. "/" or "/vendor/uPlot.iife.min.js"
  std::string_view content_type;  // e.g. "text/javascript; charset=utf-8"
  std::string_view body;
};

// Every asset, in the order of embed_assets.cmake's table.
const std::vector<Asset>& Assets();

}  // namespace flexid::dashboard
