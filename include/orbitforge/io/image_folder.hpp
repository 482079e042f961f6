#pragma once
// The frames of a video as a folder of images: every image file in the folder,
// in name order (std::string order of the file names). That order is the frame
// numbering the pipeline's frame ranges refer to.
#include <algorithm>
#include <cctype>
#include <filesystem>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"

namespace orbitforge {

// "0007.png" for (7, 4): zero-padded so that name order is frame order.
inline std::string numbered_png(int i, int digits) {
  std::string n = std::to_string(i);
  if (int(n.size()) < digits) n.insert(0, std::size_t(digits) - n.size(), '0');
  return n + ".png";
}

inline bool is_image_file_name(const std::string& name) {
  const auto dot = name.rfind('.');
  if (dot == std::string::npos || dot == 0) return false;
  std::string ext = name.substr(dot + 1);
  for (auto& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  for (const char* e : {"png", "jpg", "jpeg", "bmp", "tga", "pfm", "ppm", "pgm", "hdr", "psd", "gif"})
    if (ext == e) return true;
  return false;
}

// File names (not paths) of the images in `dir`, sorted; hidden files skipped.
inline std::vector<std::string> list_image_files(const std::string& dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  ensure(fs::is_directory(dir, ec), dir, ": not a folder of images");
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string n = e.path().filename().string();
    if (n.empty() || n[0] == '.') continue;
    if (!e.is_regular_file(ec) && !e.is_symlink(ec)) continue;
    if (is_image_file_name(n)) names.push_back(n);
  }
  ensure(!ec, dir, ": cannot list the folder: ", ec.message());
  std::sort(names.begin(), names.end());
  return names;
}

}  // namespace orbitforge
