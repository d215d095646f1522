// Fuzz target for scene files (trocar view --scene): the bounded JSON reader and every field's
// check (ranges, a rigid base pose, a camera with an up direction across its view). The reader is
// built alone (viz/scene_file_io.cpp, viz/scene_style.cpp), without the renderer.
#include "fuzz_util.hpp"
#include "viz/scene_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = trocar::fuzz::WriteInput("scene.json", data, size);
  trocar::fuzz::Expect([&] { trocar::viz::ReadSceneFile(path); });
  return 0;
}
