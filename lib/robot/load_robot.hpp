#pragma once
/// @file
/// Loading a robot description from a file, whatever its kind:
/// - `arm.urdf` — URDF; a trocar sidecar `arm.trocar.yaml` beside it is applied when present.
/// - `arm.yaml` with `urdf: arm.urdf` — a URDF plus the sidecar fields in the same file.
/// - `arm.yaml` with `dh:` — a Denavit-Hartenberg table (standard or modified) plus sidecar fields.
/// - `arm.yaml` with `links:` and `joints:` — a tree written in YAML; a joint origin is
///   `{xyz, rpy, dh: [rows]}`, X = T(xyz) R(rpy) · Π Rx(alpha) Tx(a) Rz(theta) Tz(d), so published
///   modified-DH tables can be copied in exactly.
/// - any of these may `include:` other descriptions: `{file, prefix, parent, origin}` attaches the
///   file's robot, names prefixed, under link `parent`; a first include without `parent` is the
///   base that this file extends (RobotModelBuilder::Attach).
///
/// Sidecar fields (all optional), for what URDF lacks; see robots/README.md for the full format:
///   name, tool {link, xyz, rpy}, rcm {link, xyz, rpy}, frames [{name, link, xyz, rpy}],
///   active_joints [..], held_joints [..], joint_limits {joint: {lower, upper, velocity,
///   acceleration, effort}}, closures [{name, type: four_bar, driver, coupler, rocker, cut_point,
///   cut_point_rocker}], collision {link: [geometry]}, controller {task_gains: [6]}.

#include <string>

#include "robot/dh_table.hpp"
#include "robot/robot_model.hpp"
#include "robot/urdf_loader.hpp"

namespace trocar::robot {

/// The description before validation, for composing (RobotModelBuilder::Attach).
/// @throws trocar::Error naming the file, line and field for any problem.
RobotModelBuilder LoadRobotDescription(const std::string& path, const LoadOptions& options = {});

/// The overlay of tuned controller gains beside a robot description: `arm.urdf` →
/// `arm.gains.yaml` (`gains: {jt: [wx, wy, wz, vx, vy, vz], ...}`). Loading applies it over the
/// description's own gains.
std::string GainsOverlayPath(const std::string& description);

/// @throws trocar::Error naming the file, line and field for any problem.
RobotModel LoadRobot(const std::string& path, const LoadOptions& options = {});

/// The DH table of a `dh:` YAML description. @throws trocar::Error as LoadRobot.
DhTable LoadDhTable(const std::string& path);

}  // namespace trocar::robot
