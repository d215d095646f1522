#include "common/image.hpp"

#include <algorithm>
#include <cstring>

#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPNGReader.h>
#include <vtkPNGWriter.h>
#include <vtkUnsignedCharArray.h>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar {

std::string EncodePng(const Image& image) {
  TROCAR_THROW_UNLESS(image.width > 0 && image.height > 0 &&
                          image.rgb.size() == static_cast<std::size_t>(3) * image.width * image.height,
                      "not an image to encode (" << image.width << "x" << image.height << ", "
                                                 << image.rgb.size() << " bytes)");
  vtkNew<vtkImageData> data;
  data->SetDimensions(image.width, image.height, 1);
  data->AllocateScalars(VTK_UNSIGNED_CHAR, 3);
  auto* pixels = static_cast<unsigned char*>(data->GetScalarPointer());
  const std::size_t row = static_cast<std::size_t>(3) * image.width;
  for (int y = 0; y < image.height; ++y) {  // VTK's rows run bottom to top
    std::copy_n(image.rgb.begin() + static_cast<std::ptrdiff_t>(row * y), row,
                pixels + row * (image.height - 1 - y));
  }
  vtkNew<vtkPNGWriter> writer;
  writer->WriteToMemoryOn();
  writer->SetInputData(data);
  writer->Write();
  vtkUnsignedCharArray* bytes = writer->GetResult();
  TROCAR_THROW_UNLESS(writer->GetErrorCode() == 0 && bytes && bytes->GetNumberOfTuples() > 0,
                      "the PNG could not be encoded");
  return std::string(reinterpret_cast<const char*>(bytes->GetPointer(0)),
                     static_cast<std::size_t>(bytes->GetNumberOfTuples()));
}

Image DecodePng(const std::string& bytes) {
  static const char kSignature[8] = {'\x89', 'P', 'N', 'G', '\r', '\n', '\x1a', '\n'};
  TROCAR_THROW_UNLESS(bytes.size() > 8 && std::memcmp(bytes.data(), kSignature, 8) == 0,
                      "not a PNG (no PNG signature)");
  vtkNew<vtkPNGReader> reader;
  reader->SetMemoryBuffer(bytes.data());
  reader->SetMemoryBufferLength(static_cast<vtkIdType>(bytes.size()));
  reader->Update();
  vtkImageData* data = reader->GetOutput();
  int dims[3] = {0, 0, 0};
  data->GetDimensions(dims);
  const int channels = data->GetNumberOfScalarComponents();
  TROCAR_THROW_UNLESS(reader->GetErrorCode() == 0 && dims[0] > 0 && dims[1] > 0 &&
                          data->GetScalarType() == VTK_UNSIGNED_CHAR && channels >= 1 && channels <= 4 &&
                          data->GetScalarPointer() != nullptr,
                      "not a whole 8-bit PNG");
  Image image;
  image.width = dims[0];
  image.height = dims[1];
  image.rgb.resize(static_cast<std::size_t>(3) * dims[0] * dims[1]);
  const auto* pixels = static_cast<const unsigned char*>(data->GetScalarPointer());
  const bool colour = channels >= 3;
  for (int y = 0; y < dims[1]; ++y) {
    const unsigned char* row = pixels + static_cast<std::size_t>(channels) * dims[0] * (dims[1] - 1 - y);
    for (int x = 0; x < dims[0]; ++x) {
      const unsigned char* p = row + static_cast<std::size_t>(channels) * x;
      std::uint8_t* out = &image.rgb[3 * (static_cast<std::size_t>(y) * dims[0] + x)];
      out[0] = p[0];
      out[1] = colour ? p[1] : p[0];
      out[2] = colour ? p[2] : p[0];
    }
  }
  return image;
}

void WritePng(const Image& image, const std::string& path) {
  std::string bytes;
  try {
    bytes = EncodePng(image);
  } catch (const Error& e) {
    TROCAR_THROW(path << ": " << e.what());
  }
  WriteFileAtomically(path, bytes);
}

Image ReadPng(const std::string& path) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": no such image");
  try {
    return DecodePng(ReadBinaryFile(path));
  } catch (const Error& e) {
    TROCAR_THROW(path << ": " << e.what());
  }
}

}  // namespace trocar
