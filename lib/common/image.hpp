#pragma once
/// @file
/// One RGB image type for everything trocar draws or reads back — rendered views, CT slice
/// previews, figures — and PNG through VTK's codec (libpng): any 8-bit PNG is read, PNGs are
/// written atomically.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace trocar {

/// An RGB image in memory, rows top to bottom.
struct Image {
  int width = 0, height = 0;
  std::vector<std::uint8_t> rgb;  ///< row-major, 3 bytes a pixel
  std::array<std::uint8_t, 3> Pixel(int x, int y) const {
    const std::size_t i = 3 * (static_cast<std::size_t>(y) * width + x);
    return {rgb[i], rgb[i + 1], rgb[i + 2]};
  }
};

/// PNG bytes of an image (8-bit RGB). @throws trocar::Error for an empty or inconsistent image.
std::string EncodePng(const Image& image);

/// Decodes an 8-bit PNG (grey, grey + alpha, RGB or RGBA; alpha dropped) into RGB.
/// @throws trocar::Error for anything that is not a whole PNG of that kind.
Image DecodePng(const std::string& bytes);

/// EncodePng, written atomically. @throws trocar::Error naming the path.
void WritePng(const Image& image, const std::string& path);

/// Reads a PNG file. @throws trocar::Error naming the path when it is missing or not a PNG.
Image ReadPng(const std::string& path);

}  // namespace trocar
