// Fuzz target for robot YAML descriptions, with includes: the input may include `arm.yaml` and
// `arm.urdf` (written beside it once), itself, or `robot.yaml` again (a cycle).
#include "fuzz_util.hpp"
#include "robot/load_robot.hpp"

namespace {

void WriteIncludes() {
  static bool done = false;
  if (done) return;
  done = true;
  const std::string arm =
      "links: [{name: base}, {name: l1}, {name: tool}]\n"
      "joints:\n"
      "  - {name: j1, type: revolute, parent: base, child: l1, axis: [0, 0, 1], limits: {lower: -2, upper: 2}}\n"
      "  - {name: j2, type: prismatic, parent: l1, child: tool, origin: {xyz: [0, 0, 0.1]}, axis: [0, 0, 1], limits: {lower: 0, upper: 0.2}}\n";
  trocar::fuzz::WriteInput("arm.yaml", reinterpret_cast<const uint8_t*>(arm.data()), arm.size());
  const std::string urdf =
      "<robot name=\"a\"><link name=\"b\"/><link name=\"t\"><collision><geometry><sphere radius=\"0.01\"/></geometry></collision></link>"
      "<joint name=\"j\" type=\"revolute\"><parent link=\"b\"/><child link=\"t\"/><axis xyz=\"0 0 1\"/>"
      "<limit lower=\"-1\" upper=\"1\" velocity=\"1\" effort=\"1\"/></joint></robot>\n";
  trocar::fuzz::WriteInput("arm.urdf", reinterpret_cast<const uint8_t*>(urdf.data()), urdf.size());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  WriteIncludes();
  const std::string path = trocar::fuzz::WriteInput("robot.yaml", data, size);
  trocar::robot::LoadOptions options;
  options.load_meshes = false;
  trocar::fuzz::Expect([&] { trocar::robot::LoadRobot(path, options).name(); });
  return 0;
}
