#pragma once
/// @file
/// Which network device drives what (docs/network-devices.md): a YAML file mapping OpenIGTLink
/// device names to arms (a plan's psm1, psm2, ecm, or a robot's tool) or to a teaching pointer,
/// with each device's units, motion scaling and the rotation from the device to the camera.
///
///     devices:
///       - {name: left,  arm: psm1, units: mm, scale: 3, device_to_camera_rpy: [0, 0, 0]}
///       - {name: right, arm: psm2, units: m}
///       - {name: senior, pointer: true}

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

namespace trocar::control {

struct DeviceBinding {
  std::string name;         ///< the device name in its OpenIGTLink headers (at most 20 bytes)
  std::string arm;          ///< the arm it drives ("" for a pointer)
  bool pointer = false;     ///< a teaching pointer: drawn, drives nothing
  double units = 0.001;     ///< metres per unit of its translations (OpenIGTLink: mm)
  std::optional<double> scale;  ///< device:tool motion ratio (3 means 3:1); unset: the command's
  /// The device's frame in the camera's: hand motions along device axes are read as these
  /// camera-frame motions (e.g. a device mounted turned by 90° about its vertical).
  Eigen::Matrix3d R_CD = Eigen::Matrix3d::Identity();
};

struct DeviceConfig {
  std::string path;
  std::vector<DeviceBinding> devices;
  /// The binding of `arm`, or nullptr.
  const DeviceBinding* ForArm(const std::string& arm) const;
};

/// Reads a device file. @throws trocar::Error naming the file, line, field and what was expected
/// (unknown keys, a name over 20 bytes or used twice, two devices on one arm, two pointers, units other than
/// mm, m or a positive number of metres, a non-positive scale).
DeviceConfig ReadDeviceConfig(const std::string& path);

}  // namespace trocar::control
