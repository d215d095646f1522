// Fuzz target for URDF robots: the XML scan, urdfdom, and the robot model built from it.
#include "fuzz_util.hpp"
#include "robot/load_robot.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = trocar::fuzz::WriteInput("robot.urdf", data, size);
  trocar::robot::LoadOptions options;
  options.load_meshes = false;
  trocar::fuzz::Expect([&] { trocar::robot::LoadRobot(path, options).name(); });
  return 0;
}
