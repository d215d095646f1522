#include "control/device_config.hpp"

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
        TROCAR_THROW_UNLESS(b.units > 0 && b.units <= 1000,
                            y.Where(u, at + ".units") << ": " << b.units
                                                      << ": expected mm, m, or metres per unit (> 0)");
      }
    }
    if (d["scale"]) {
      b.scale = y.Number(d["scale"], at + ".scale");
      TROCAR_THROW_UNLESS(*b.scale > 0, y.Where(d["scale"], at + ".scale")
                                            << ": " << *b.scale << ": expected a positive motion ratio");
    }
    if (d["device_to_camera_rpy"]) {
      const Eigen::Vector3d rpy = y.Vector3(d["device_to_camera_rpy"], at + ".device_to_camera_rpy");
      b.R_CD = RotationFromRpy(rpy);
    }
    config.devices.push_back(b);
  }
  return config;
}

}  // namespace trocar::control
