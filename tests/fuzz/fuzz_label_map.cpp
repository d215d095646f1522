// Fuzz target for label maps: a 3D Slicer segmentation (.seg.nrrd, names in its key/value pairs)
// when the input starts with "NRRD", else a JSON names sidecar for a fixed small TotalSegmentator-
// style NIfTI label map.
#include <cstring>

#include "fuzz_util.hpp"
#include "patient/label_map.hpp"

namespace {

std::string LabelNifti() {
  std::string h(352, '\0');
  auto put = [&](std::size_t at, const void* data, std::size_t n) { std::memcpy(&h[at], data, n); };
  const std::int32_t size = 348;
  put(0, &size, 4);
  const std::int16_t dims[8] = {3, 4, 4, 2, 1, 1, 1, 1};
  put(40, dims, 16);
  const std::int16_t datatype = 2, bitpix = 8;
  put(70, &datatype, 2);
  put(72, &bitpix, 2);
  const float pixdim[4] = {1, 1, 1, 1};
  put(76, pixdim, 16);
  const float offset = 352;
  put(108, &offset, 4);
  put(344, "n+1", 4);
  std::string voxels(32, '\0');
  for (int i = 0; i < 32; ++i) voxels[i] = static_cast<char>(i % 4);
  return h + voxels;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size >= 4 && std::memcmp(data, "NRRD", 4) == 0) {
    const std::string path = trocar::fuzz::WriteInput("labels.seg.nrrd", data, size);
    trocar::fuzz::Expect([&] { trocar::patient::LoadLabelMap(path); });
    return 0;
  }
  static const std::string nifti = [] {
    const std::string bytes = LabelNifti();
    return trocar::fuzz::WriteInput("labels.nii", reinterpret_cast<const uint8_t*>(bytes.data()),
                                    bytes.size());
  }();
  const std::string names = trocar::fuzz::WriteInput("labels.json", data, size);
  trocar::fuzz::Expect([&] { trocar::patient::LoadLabelMap(nifti, names); });
  return 0;
}
