#include "control/device_config.hpp"

#include <algorithm>
#include <cmath>
#include <set>

#include "common/error.hpp"
#include "common/geometry.hpp"
#include "common/yaml_util.hpp"

namespace trocar::control {

const DeviceBinding* DeviceConfig::ForArm(const std::string& arm) const {
  for (const DeviceBinding& d : devices)
    if (!d.pointer && d.arm == arm) return &d;
  return nullptr;
}

DeviceConfig ReadDeviceConfig(const std::string& path) {
  const YamlReader y = YamlReader::Load(path);
  const YAML::Node& root = y.root();
  y.ExpectMap(root, "", {"devices"});
  const YAML::Node list = y.Require(root, "devices", "");
  y.ExpectSequence(list, "devices");
  TROCAR_THROW_UNLESS(list.size() > 0, y.Where(list, "devices") << ": no devices (expected a list of "
                                                                   "{name, arm or pointer: true})");
  DeviceConfig config;
  config.path = path;
  std::set<std::string> names, arms;
  std::string pointer;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YAML::Node d = list[i];
    const std::string at = "devices[" + std::to_string(i) + "]";
    y.ExpectMap(d, at, {"name", "arm", "pointer", "units", "scale", "device_to_camera_rpy"});
    DeviceBinding b;
    b.name = y.String(y.Require(d, "name", at), at + ".name");
    TROCAR_THROW_UNLESS(!b.name.empty() && b.name.size() <= 20,
                        y.Where(d["name"], at + ".name") << ": '" << b.name
                                                         << "': expected 1 to 20 characters (OpenIGTLink's device name)");
    // Printable ASCII only: a control byte (a NUL, a newline) in a name no device can send.
    TROCAR_THROW_UNLESS(std::all_of(b.name.begin(), b.name.end(),
                                    [](char c) { return c >= 0x20 && c <= 0x7e; }),
                        y.Where(d["name"], at + ".name")
                            << ": the name holds a control or non-ASCII byte; an OpenIGTLink device "
                               "name is printable ASCII");
    TROCAR_THROW_UNLESS(names.insert(b.name).second,
                        y.Where(d["name"], at + ".name") << ": device '" << b.name << "' is listed twice");
    b.pointer = d["pointer"] ? y.Bool(d["pointer"], at + ".pointer") : false;
    if (d["arm"]) b.arm = y.String(d["arm"], at + ".arm");
    TROCAR_THROW_UNLESS(b.pointer != !b.arm.empty(),
                        y.Where(d, at) << ": device '" << b.name
                                       << "': give either arm: NAME (psm1, psm2, ecm, tool) or pointer: true");
    TROCAR_THROW_UNLESS(!b.pointer || pointer.empty(),
                        y.Where(d, at) << ": device '" << b.name << "': '" << pointer
                                       << "' is the pointer already (one pointer at most)");
    if (b.pointer) pointer = b.name;
    TROCAR_THROW_UNLESS(b.pointer || arms.insert(b.arm).second,
                        y.Where(d["arm"], at + ".arm") << ": arm '" << b.arm << "' already has a device");
    if (d["units"]) {
      const YAML::Node u = d["units"];
      const std::string text = u.IsScalar() ? u.Scalar() : "";
      if (text == "mm") {
        b.units = 0.001;
      } else if (text == "m") {
        b.units = 1.0;
      } else {
        b.units = y.Number(u, at + ".units");
        // Physical: from micrometres to metres per unit (a device reporting in km or in 1e-300 m
        // is a typing error, and its session would run to infinite errors).
        TROCAR_THROW_UNLESS(b.units >= 1e-6 && b.units <= 1.0,
                            y.Where(u, at + ".units") << ": " << b.units
                                                      << ": expected mm, m, or metres per unit "
                                                         "from 1e-6 (um) to 1 (m)");
      }
    }
    if (d["scale"]) {
      b.scale = y.Number(d["scale"], at + ".scale");
      // Motion scaling as surgeons use it (the da Vinci's 1:1 to 5:1, and fine 10:1), with room
      // either way; 1e-300 or 1e300 is not a ratio a hand can drive.
      TROCAR_THROW_UNLESS(*b.scale >= 0.01 && *b.scale <= 100,
                          y.Where(d["scale"], at + ".scale")
                              << ": " << *b.scale
                              << ": expected a motion scaling (device:tool) from 0.01 to 100");
    }
    if (d["device_to_camera_rpy"]) {
      const Eigen::Vector3d rpy = y.Vector3(d["device_to_camera_rpy"], at + ".device_to_camera_rpy");
      TROCAR_THROW_UNLESS(rpy.allFinite() && rpy.cwiseAbs().maxCoeff() <= 2 * M_PI + 1e-9,
                          y.Where(d["device_to_camera_rpy"], at + ".device_to_camera_rpy")
                              << ": angles within one turn (|angle| <= 360 deg) expected");
      b.R_CD = RotationFromRpy(rpy);
    }
    config.devices.push_back(b);
  }
  return config;
}

}  // namespace trocar::control
