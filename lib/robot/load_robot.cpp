#include "robot/load_robot.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/geometry.hpp"
#include "common/limits.hpp"
#include "common/yaml_util.hpp"

namespace trocar::robot {
namespace {

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

Eigen::Isometry3d ReadPose(const YamlReader& r, const YAML::Node& node, const std::string& path) {
  const Eigen::Vector3d xyz =
      node["xyz"] ? r.Vector3(node["xyz"], path + ".xyz") : Eigen::Vector3d::Zero();
  const Eigen::Vector3d rpy =
      node["rpy"] ? r.Vector3(node["rpy"], path + ".rpy") : Eigen::Vector3d::Zero();
  // Physical ranges (issue #44, item 3), as for a URDF's <origin>: an angle of 1e308 rad is a
  // finite number and some rotation, and nobody meant it.
  TROCAR_THROW_UNLESS(xyz.cwiseAbs().maxCoeff() <= 100.0,
                      r.Where(node["xyz"], path + ".xyz") << ": outside 100 m either way");
  TROCAR_THROW_UNLESS(rpy.cwiseAbs().maxCoeff() <= 2 * M_PI + 1e-9,
                      r.Where(node["rpy"], path + ".rpy")
                          << ": outside one turn either way (|angle| <= 2 pi rad)");
  return MakeTransform(xyz, rpy);
}

Geometry ReadGeometry(const YamlReader& r, const YAML::Node& node, const std::string& path,
                      const LoadOptions& options) {
  r.ExpectMap(node, path,
              {"shape", "radius", "length", "size", "file", "scale", "xyz", "rpy", "rgba"});
  Geometry g;
  const std::string shape = r.String(r.Require(node, "shape", path), path + ".shape");
  g.X_LG = ReadPose(r, node, path);
  if (node["rgba"]) {
    const std::vector<double> rgba = r.Numbers(node["rgba"], path + ".rgba");
    TROCAR_THROW_UNLESS(rgba.size() == 4, r.Where(node["rgba"], path + ".rgba")
                                              << ": expected 4 numbers, got " << rgba.size());
    g.rgba << rgba[0], rgba[1], rgba[2], rgba[3];
  }
  auto positive = [&](const char* key) {
    const double v = r.Number(r.Require(node, key, path), path + "." + key);
    TROCAR_THROW_UNLESS(v > 0, r.Where(node[key], path + "." + key)
                                   << ": " << v << " must be positive");
    return v;
  };
  if (shape == "box") {
    g.shape = Geometry::Shape::kBox;
    g.size = r.Vector3(r.Require(node, "size", path), path + ".size");
  } else if (shape == "sphere") {
    g.shape = Geometry::Shape::kSphere;
    g.size[0] = positive("radius");
  } else if (shape == "cylinder" || shape == "capsule") {
    g.shape = shape == "cylinder" ? Geometry::Shape::kCylinder : Geometry::Shape::kCapsule;
    g.size[0] = positive("radius");
    g.size[1] = r.Number(r.Require(node, "length", path), path + ".length");
  } else if (shape == "mesh") {
    g.shape = Geometry::Shape::kMesh;
    const std::string file = r.String(r.Require(node, "file", path), path + ".file");
    g.mesh_file = ResolveMeshPath(file, r.file(), options.package_paths);
    if (node["scale"]) g.mesh_scale = r.Vector3(node["scale"], path + ".scale");
    TROCAR_THROW_UNLESS(IsRegularFile(g.mesh_file), r.Where(node["file"], path + ".file")
                                                        << ": mesh file '" << file
                                                        << "' not found (looked for "
                                                        << g.mesh_file << ")");
    if (options.load_meshes) g.mesh = LoadMesh(g.mesh_file, g.mesh_scale);
  } else {
    TROCAR_THROW(r.Where(node["shape"], path + ".shape")
                 << ": unknown shape '" << shape
                 << "' (expected box, cylinder, sphere, capsule or mesh)");
  }
  return g;
}

std::vector<Geometry> ReadGeometryList(const YamlReader& r, const YAML::Node& node,
                                       const std::string& path, const LoadOptions& options) {
  r.ExpectSequence(node, path);
  std::vector<Geometry> out;
  for (std::size_t i = 0; i < node.size(); ++i) {
    out.push_back(ReadGeometry(r, node[i], path + "[" + std::to_string(i) + "]", options));
  }
  return out;
}

void ReadLimits(const YamlReader& r, const YAML::Node& node, const std::string& path,
                JointLimits* limits) {
  r.ExpectMap(node, path, {"lower", "upper", "velocity", "acceleration", "effort"});
  limits->lower = r.BoundOr(node, "lower", path, limits->lower);
  limits->upper = r.BoundOr(node, "upper", path, limits->upper);
  limits->velocity = r.BoundOr(node, "velocity", path, limits->velocity);
  limits->acceleration = r.BoundOr(node, "acceleration", path, limits->acceleration);
  limits->effort = r.BoundOr(node, "effort", path, limits->effort);
  TROCAR_THROW_UNLESS(limits->lower <= limits->upper,
                      r.Where(node, path) << ": lower limit " << limits->lower
                                          << " > upper limit " << limits->upper);
  for (const char* key : {"velocity", "acceleration"}) {
    if (node[key]) {
      const double v = r.Bound(node[key], path + "." + key);
      TROCAR_THROW_UNLESS(v > 0, r.Where(node[key], path + "." + key)
                                     << ": " << v << " must be positive");
    }
  }
}

JointType ReadJointType(const YamlReader& r, const YAML::Node& node, const std::string& path) {
  const std::string type = r.String(node, path);
  if (type == "revolute") return JointType::kRevolute;
  if (type == "prismatic") return JointType::kPrismatic;
  TROCAR_THROW(r.Where(node, path) << ": joint type '" << type
                                   << "' (expected revolute or prismatic)");
}

const std::initializer_list<const char*> kTopLevelKeys = {
    "name",         "tool",     "rcm",       "frames",     "active_joints", "held_joints",
    "joint_limits", "closures", "collision", "controller", "urdf",          "dh",
    "links",        "joints",   "include",   "home",       "appearance"};

// The sidecar's `appearance:` (robot_defaults.hpp, docs/robot-appearance.md): another
// description's meshes for some links to wear where drawn. Its file may be missing (the robot is
// then drawn with its own shapes, and the viewer says so); its names are checked against the
// dressing description when it is drawn, and against this one here.
Appearance ReadAppearance(const YamlReader& r, const YAML::Node& node) {
  r.ExpectMap(node, "appearance", {"urdf", "links", "joints", "tolerance", "tolerances"});
  Appearance out;
  out.where = r.file() + ": appearance";
  out.urdf = JoinPath(ParentDirectory(r.file()),
                      r.String(r.Require(node, "urdf", "appearance"), "appearance.urdf"));
  const YAML::Node links = r.Require(node, "links", "appearance");
  TROCAR_THROW_UNLESS(links.IsMap() && links.size() > 0,
                      r.Where(links, "appearance.links")
                          << ": expected a mapping from this robot's links to the links whose "
                             "meshes they wear");
  for (const auto& entry : links) {
    out.links.push_back(
        {r.String(entry.first, "appearance.links"), r.String(entry.second, "appearance.links")});
  }
  const YAML::Node joints = r.Require(node, "joints", "appearance");
  TROCAR_THROW_UNLESS(joints.IsMap() && joints.size() > 0,
                      r.Where(joints, "appearance.joints")
                          << ": expected a mapping from this robot's joints to the joints they "
                             "drive (a name, or {drives, multiplier, offset})");
  for (const auto& entry : joints) {
    Appearance::Drive drive;
    drive.joint = r.String(entry.first, "appearance.joints");
    const std::string path = "appearance.joints." + drive.joint;
    if (entry.second.IsMap()) {
      r.ExpectMap(entry.second, path, {"drives", "multiplier", "offset"});
      drive.drives = r.String(r.Require(entry.second, "drives", path), path + ".drives");
      if (entry.second["multiplier"]) {
        drive.multiplier = r.Number(entry.second["multiplier"], path + ".multiplier");
        TROCAR_THROW_UNLESS(std::abs(drive.multiplier) >= 1e-3 && std::abs(drive.multiplier) <= 1e3,
                            r.Where(entry.second["multiplier"], path + ".multiplier")
                                << ": expected a magnitude between 0.001 and 1000");
      }
      if (entry.second["offset"]) {
        drive.offset = r.Number(entry.second["offset"], path + ".offset");
        TROCAR_THROW_UNLESS(std::abs(drive.offset) <= 100.0,
                            r.Where(entry.second["offset"], path + ".offset")
                                << ": expected at most 100 (rad or m) either way");
      }
    } else {
      drive.drives = r.String(entry.second, path);
    }
    out.joints.push_back(drive);
  }
  auto read_tolerance = [&](const YAML::Node& value, const std::string& path) {
    const double m = r.Number(value, path);
    TROCAR_THROW_UNLESS(m >= 1e-4 && m <= 0.05, r.Where(value, path)
                                                    << ": expected 0.0001 to 0.05 m");
    return m;
  };
  if (node["tolerance"]) out.tolerance = read_tolerance(node["tolerance"], "appearance.tolerance");
  if (node["tolerances"]) {
    TROCAR_THROW_UNLESS(node["tolerances"].IsMap(),
                        r.Where(node["tolerances"], "appearance.tolerances")
                            << ": expected a mapping from links to metres");
    for (const auto& entry : node["tolerances"]) {
      const std::string link = r.String(entry.first, "appearance.tolerances");
      const bool worn = std::any_of(out.links.begin(), out.links.end(),
                                    [&](const Appearance::Wear& w) { return w.link == link; });
      TROCAR_THROW_UNLESS(worn, r.Where(entry.first, "appearance.tolerances")
                                    << ": '" << link << "' wears nothing (appearance.links)");
      out.tolerances[link] = read_tolerance(entry.second, "appearance.tolerances." + link);
    }
  }
  return out;
}

// Applies the sidecar fields of `root` to `builder`.
void ApplySidecar(const YamlReader& r, const YAML::Node& root, RobotModelBuilder* builder,
                  const LoadOptions& options) {
  r.ExpectMap(root, "", kTopLevelKeys);
  if (root["name"]) builder->set_name(r.String(root["name"], "name"));
  auto read_frame = [&](const YAML::Node& node, const std::string& path,
                        const std::string& default_name) {
    r.ExpectMap(node, path, {"name", "link", "xyz", "rpy"});
    RobotModelBuilder::FrameSpec frame;
    frame.name = node["name"] ? r.String(node["name"], path + ".name") : default_name;
    frame.link = r.String(r.Require(node, "link", path), path + ".link");
    TROCAR_THROW_UNLESS(builder->FindLink(frame.link) != nullptr,
                        r.Where(node["link"], path + ".link")
                            << ": no link named '" << frame.link << "'");
    frame.X_LF = ReadPose(r, node, path);
    return frame;
  };
  if (root["tool"]) builder->SetTool(read_frame(root["tool"], "tool", "tool"));
  if (root["rcm"]) builder->SetRcm(read_frame(root["rcm"], "rcm", "rcm"));
  if (root["frames"]) {
    r.ExpectSequence(root["frames"], "frames");
    for (std::size_t i = 0; i < root["frames"].size(); ++i) {
      const std::string path = "frames[" + std::to_string(i) + "]";
      const YAML::Node node = root["frames"][i];
      r.Require(node, "name", path);
      builder->AddFrame(read_frame(node, path, ""));
    }
  }
  auto check_joint = [&](const YAML::Node& node, const std::string& path) {
    const std::string name = r.String(node, path);
    TROCAR_THROW_UNLESS(builder->FindJoint(name) != nullptr,
                        r.Where(node, path) << ": no joint named '" << name << "'");
    return name;
  };
  if (root["active_joints"]) {
    const YAML::Node list = root["active_joints"];
    r.ExpectSequence(list, "active_joints");
    std::vector<std::string> names;
    for (std::size_t i = 0; i < list.size(); ++i) {
      names.push_back(check_joint(list[i], "active_joints[" + std::to_string(i) + "]"));
    }
    builder->SetActiveJoints(names);
  }
  if (root["held_joints"]) {
    const YAML::Node list = root["held_joints"];
    r.ExpectSequence(list, "held_joints");
    for (std::size_t i = 0; i < list.size(); ++i) {
      builder->GetJoint(check_joint(list[i], "held_joints[" + std::to_string(i) + "]")).held =
          true;
    }
  }
  if (root["joint_limits"]) {
    const YAML::Node map = root["joint_limits"];
    TROCAR_THROW_UNLESS(map.IsMap(), r.Where(map, "joint_limits") << ": expected a mapping");
    for (const auto& entry : map) {
      const std::string name = check_joint(entry.first, "joint_limits");
      ReadLimits(r, entry.second, "joint_limits." + name, &builder->GetJoint(name).limits);
    }
  }
  if (root["closures"]) {
    const YAML::Node list = root["closures"];
    r.ExpectSequence(list, "closures");
    for (std::size_t i = 0; i < list.size(); ++i) {
      const std::string path = "closures[" + std::to_string(i) + "]";
      const YAML::Node node = list[i];
      r.ExpectMap(node, path, {"name", "type", "driver", "coupler", "rocker", "cut_point",
                               "cut_point_rocker"});
      const std::string type = r.String(r.Require(node, "type", path), path + ".type");
      TROCAR_THROW_UNLESS(type == "four_bar", r.Where(node["type"], path + ".type")
                                                  << ": closure type '" << type
                                                  << "' (expected four_bar)");
      RobotModelBuilder::FourBarSpec spec;
      spec.name = node["name"] ? r.String(node["name"], path + ".name") : path;
      spec.driver = check_joint(r.Require(node, "driver", path), path + ".driver");
      spec.coupler = check_joint(r.Require(node, "coupler", path), path + ".coupler");
      spec.rocker = check_joint(r.Require(node, "rocker", path), path + ".rocker");
      spec.p_C3 = r.Vector3(r.Require(node, "cut_point", path), path + ".cut_point");
      if (node["cut_point_rocker"]) {
        spec.p_B3 = r.Vector3(node["cut_point_rocker"], path + ".cut_point_rocker");
      }
      builder->AddFourBar(spec);
    }
  }
  if (root["collision"]) {
    const YAML::Node map = root["collision"];
    TROCAR_THROW_UNLESS(map.IsMap(), r.Where(map, "collision") << ": expected a mapping");
    for (const auto& entry : map) {
      const std::string link = r.String(entry.first, "collision");
      TROCAR_THROW_UNLESS(builder->FindLink(link) != nullptr,
                          r.Where(entry.first, "collision") << ": no link named '" << link << "'");
      auto shapes = ReadGeometryList(r, entry.second, "collision." + link, options);
      auto& collisions = builder->GetLink(link).collisions;
      collisions.insert(collisions.end(), shapes.begin(), shapes.end());
    }
  }
  if (root["home"]) builder->SetHome(r.Numbers(root["home"], "home"));
  if (root["appearance"]) builder->AddAppearance(ReadAppearance(r, root["appearance"]));
  if (root["controller"]) {
    const YAML::Node node = root["controller"];
    r.ExpectMap(node, "controller", {"task_gains", "gains"});
    auto read_gains = [&](const YAML::Node& list, const std::string& path) {
      const std::vector<double> gains = r.Numbers(list, path);
      TROCAR_THROW_UNLESS(gains.size() == 6, r.Where(list, path)
                                                 << ": expected 6 values [wx wy wz vx vy vz], got "
                                                 << gains.size());
      return Eigen::VectorXd(Eigen::Map<const Eigen::VectorXd>(gains.data(), 6));
    };
    if (node["task_gains"]) {
      builder->controller().task_gains = read_gains(node["task_gains"], "controller.task_gains");
    }
    if (node["gains"]) {
      TROCAR_THROW_UNLESS(node["gains"].IsMap(), r.Where(node["gains"], "controller.gains")
                                                     << ": expected a mapping from controller "
                                                        "name to 6 gains");
      for (const auto& entry : node["gains"]) {
        const std::string name = r.String(entry.first, "controller.gains");
        builder->controller().gains[name] = read_gains(entry.second, "controller.gains." + name);
      }
    }
  }
}

DhTable ReadDhTable(const YamlReader& r, const YAML::Node& dh, const LoadOptions& options) {
  r.ExpectMap(dh, "dh", {"convention", "base_link", "base", "joints", "tool"});
  DhTable table;
  const std::string convention = r.String(r.Require(dh, "convention", "dh"), "dh.convention");
  if (convention == "standard") {
    table.convention = DhConvention::kStandard;
  } else if (convention == "modified") {
    table.convention = DhConvention::kModified;
  } else {
    TROCAR_THROW(r.Where(dh["convention"], "dh.convention")
                 << ": '" << convention << "' (expected standard or modified)");
  }
  if (dh["base_link"]) table.base_link = r.String(dh["base_link"], "dh.base_link");
  if (dh["base"]) {
    r.ExpectMap(dh["base"], "dh.base", {"xyz", "rpy"});
    table.X_B0 = ReadPose(r, dh["base"], "dh.base");
  }
  if (dh["tool"]) {
    r.ExpectMap(dh["tool"], "dh.tool", {"xyz", "rpy"});
    table.X_NT = ReadPose(r, dh["tool"], "dh.tool");
  }
  const YAML::Node joints = r.Require(dh, "joints", "dh");
  r.ExpectSequence(joints, "dh.joints");
  TROCAR_THROW_UNLESS(joints.size() > 0, r.Where(joints, "dh.joints") << ": no joints");
  for (std::size_t i = 0; i < joints.size(); ++i) {
    const std::string path = "dh.joints[" + std::to_string(i) + "]";
    const YAML::Node node = joints[i];
    r.ExpectMap(node, path, {"name", "link", "type", "alpha", "a", "d", "theta", "offset",
                             "limits", "visual", "collision"});
    DhRow row;
    row.joint = node["name"] ? r.String(node["name"], path + ".name")
                             : "joint_" + std::to_string(i + 1);
    row.link = node["link"] ? r.String(node["link"], path + ".link")
                            : "link_" + std::to_string(i + 1);
    row.type = ReadJointType(r, r.Require(node, "type", path), path + ".type");
    row.alpha = r.NumberOr(node, "alpha", path, 0.0);
    row.a = r.NumberOr(node, "a", path, 0.0);
    row.d = r.NumberOr(node, "d", path, 0.0);
    row.theta = r.NumberOr(node, "theta", path, 0.0);
    row.offset = r.NumberOr(node, "offset", path, 0.0);
    if (node["limits"]) ReadLimits(r, node["limits"], path + ".limits", &row.limits);
    if (node["visual"]) {
      row.visuals = ReadGeometryList(r, node["visual"], path + ".visual", options);
    }
    if (node["collision"]) {
      row.collisions = ReadGeometryList(r, node["collision"], path + ".collision", options);
    }
    table.rows.push_back(std::move(row));
  }
  return table;
}

// X = T(xyz) R(rpy) · Π Rx(alpha) Tx(a) Rz(theta) Tz(d) over the `dh` rows (modified DH).
Eigen::Isometry3d ReadOrigin(const YamlReader& r, const YAML::Node& node, const std::string& path) {
  r.ExpectMap(node, path, {"xyz", "rpy", "dh"});
  Eigen::Isometry3d X = ReadPose(r, node, path);
  if (node["dh"]) {
    const YAML::Node dh = node["dh"];
    const bool list = dh.IsSequence();
    const std::size_t count = list ? dh.size() : 1;
    for (std::size_t i = 0; i < count; ++i) {
      const YAML::Node row = list ? dh[i] : dh;
      const std::string row_path = path + ".dh" + (list ? "[" + std::to_string(i) + "]" : "");
      r.ExpectMap(row, row_path, {"alpha", "a", "theta", "d"});
      X = X * RotX(r.NumberOr(row, "alpha", row_path, 0.0)) *
          TransX(r.NumberOr(row, "a", row_path, 0.0)) *
          RotZ(r.NumberOr(row, "theta", row_path, 0.0)) *
          TransZ(r.NumberOr(row, "d", row_path, 0.0));
    }
  }
  return X;
}

void ReadTree(const YamlReader& r, const YAML::Node& root, RobotModelBuilder* builder,
              const LoadOptions& options) {
  if (root["links"]) {
    const YAML::Node links = root["links"];
    r.ExpectSequence(links, "links");
    for (std::size_t i = 0; i < links.size(); ++i) {
      const std::string path = "links[" + std::to_string(i) + "]";
      const YAML::Node node = links[i];
      r.ExpectMap(node, path, {"name", "visual", "collision"});
      const std::string name = r.String(r.Require(node, "name", path), path + ".name");
      TROCAR_THROW_UNLESS(builder->FindLink(name) == nullptr,
                          r.Where(node["name"], path + ".name")
                              << ": link '" << name << "' is defined twice");
      RobotModelBuilder::LinkSpec& link = builder->AddLink(name);
      if (node["visual"]) {
        link.visuals = ReadGeometryList(r, node["visual"], path + ".visual", options);
      }
      if (node["collision"]) {
        link.collisions = ReadGeometryList(r, node["collision"], path + ".collision", options);
      }
    }
  }
  if (!root["joints"]) return;
  const YAML::Node joints = root["joints"];
  r.ExpectSequence(joints, "joints");
  for (std::size_t i = 0; i < joints.size(); ++i) {
    const std::string path = "joints[" + std::to_string(i) + "]";
    const YAML::Node node = joints[i];
    r.ExpectMap(node, path,
                {"name", "type", "parent", "child", "origin", "axis", "limits", "mimic"});
    const std::string name = r.String(r.Require(node, "name", path), path + ".name");
    TROCAR_THROW_UNLESS(builder->FindJoint(name) == nullptr,
                        r.Where(node["name"], path + ".name")
                            << ": joint '" << name << "' is defined twice");
    const std::string type = r.String(r.Require(node, "type", path), path + ".type");
    RobotModelBuilder::JointSpec& joint = builder->AddJoint(name);
    if (type == "revolute" || type == "continuous") {
      joint.type = JointType::kRevolute;
    } else if (type == "prismatic") {
      joint.type = JointType::kPrismatic;
    } else if (type == "fixed") {
      joint.type = JointType::kFixed;
    } else {
      TROCAR_THROW(r.Where(node["type"], path + ".type")
                   << ": joint type '" << type
                   << "' (expected revolute, continuous, prismatic or fixed)");
    }
    for (const char* key : {"parent", "child"}) {
      const std::string link = r.String(r.Require(node, key, path), path + "." + key);
      TROCAR_THROW_UNLESS(builder->FindLink(link) != nullptr,
                          r.Where(node[key], path + "." + key)
                              << ": no link named '" << link << "'");
      (std::string(key) == "parent" ? joint.parent : joint.child) = link;
    }
    if (node["origin"]) joint.X_PJ = ReadOrigin(r, node["origin"], path + ".origin");
    if (node["axis"]) joint.axis = r.Vector3(node["axis"], path + ".axis");
    if (node["limits"]) ReadLimits(r, node["limits"], path + ".limits", &joint.limits);
    if (node["mimic"]) {
      const YAML::Node mimic = node["mimic"];
      r.ExpectMap(mimic, path + ".mimic", {"joint", "multiplier", "offset"});
      joint.mimic_master = r.String(r.Require(mimic, "joint", path + ".mimic"), path + ".mimic.joint");
      joint.mimic_multiplier = r.NumberOr(mimic, "multiplier", path + ".mimic", 1.0);
      joint.mimic_offset = r.NumberOr(mimic, "offset", path + ".mimic", 0.0);
    }
  }
}

struct IncludeSpec {
  std::string file;
  std::string prefix;
  std::string parent;
  Eigen::Isometry3d X_PC = Eigen::Isometry3d::Identity();
  std::string where;
};

std::vector<IncludeSpec> ReadIncludes(const YamlReader& r, const YAML::Node& root) {
  std::vector<IncludeSpec> out;
  if (!root["include"]) return out;
  const YAML::Node list = root["include"];
  r.ExpectSequence(list, "include");
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string path = "include[" + std::to_string(i) + "]";
    const YAML::Node node = list[i];
    r.ExpectMap(node, path, {"file", "prefix", "parent", "origin"});
    IncludeSpec spec;
    spec.where = r.Where(node, path);
    spec.file = JoinPath(ParentDirectory(r.file()),
                         r.String(r.Require(node, "file", path), path + ".file"));
    if (node["prefix"]) spec.prefix = r.String(node["prefix"], path + ".prefix");
    if (node["parent"]) spec.parent = r.String(node["parent"], path + ".parent");
    if (node["origin"]) spec.X_PC = ReadOrigin(r, node["origin"], path + ".origin");
    TROCAR_THROW_UNLESS(!spec.parent.empty() || i == 0,
                        spec.where << ": only the first include may omit 'parent' (it becomes "
                                      "the base of this description)");
    out.push_back(spec);
  }
  return out;
}

// The files being loaded (open includes, for cycles and depth) and how many were loaded in all:
// includes that fan out (each file including the next several times) grow exponentially with
// depth, so the total is bounded too.
struct IncludeStack {
  std::vector<std::string> open;
  int loaded = 0;
  std::string root;
};

RobotModelBuilder LoadDescription(const std::string& path, const LoadOptions& options,
                                  IncludeStack* stack);

RobotModelBuilder LoadYamlDescription(const std::string& path, const LoadOptions& options,
                                      IncludeStack* stack) {
  const YamlReader r = YamlReader::Load(path);
  const YAML::Node& root = r.root();
  const std::vector<IncludeSpec> includes = ReadIncludes(r, root);
  const int kinds = (root["urdf"] ? 1 : 0) + (root["dh"] ? 1 : 0) +
                    (root["links"] || root["joints"] ? 1 : 0) +
                    (!includes.empty() && includes[0].parent.empty() ? 1 : 0);
  TROCAR_THROW_UNLESS(kinds > 0, r.Where(root, "")
                                     << ": a robot YAML needs 'urdf: <file>', a 'dh:' table, "
                                        "'links:'/'joints:', or a first 'include' without parent");
  TROCAR_THROW_UNLESS(kinds == 1 || (kinds == 2 && (root["links"] || root["joints"]) &&
                                     !includes.empty() && includes[0].parent.empty()),
                      r.Where(root, "") << ": give only one of 'urdf', 'dh', or a base include "
                                           "(links and joints may extend a base include)");
  RobotModelBuilder builder(std::filesystem::path(path).stem().string(), path);
  auto include = [&](const IncludeSpec& spec) {
    RobotModelBuilder sub = LoadDescription(spec.file, options, stack);
    try {
      builder.Attach(sub, spec.prefix, spec.parent, spec.X_PC);
    } catch (const Error& e) {
      TROCAR_THROW(spec.where << ": " << e.what());
    }
  };
  std::size_t next_include = 0;
  if (root["urdf"]) {
    builder = ParseUrdf(JoinPath(ParentDirectory(path), r.String(root["urdf"], "urdf")), options);
  } else if (root["dh"]) {
    AddDhChain(ReadDhTable(r, root["dh"], options), &builder);
  } else if (!includes.empty() && includes[0].parent.empty()) {
    include(includes[0]);
    next_include = 1;
  }
  ReadTree(r, root, &builder, options);
  for (; next_include < includes.size(); ++next_include) include(includes[next_include]);
  ApplySidecar(r, root, &builder, options);
  return builder;
}

RobotModelBuilder LoadDescription(const std::string& path, const LoadOptions& options,
                                  IncludeStack* stack) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": robot description not found");
  const std::string canonical = std::filesystem::weakly_canonical(path).string();
  for (const std::string& open : stack->open) {
    TROCAR_THROW_UNLESS(open != canonical, path << ": included from itself (include cycle)");
  }
  TROCAR_THROW_UNLESS(stack->open.size() < 16, path << ": includes nested more than 16 deep");
  const int max_files = Limits().max_includes;
  TROCAR_THROW_UNLESS(stack->loaded < max_files,
                      path << ": " << stack->root << " loads more than " << max_files
                           << " robot files in all (includes that include others several times "
                              "multiply) "
                           << LimitHint(static_cast<std::uint64_t>(max_files),
                                        "TROCAR_MAX_INCLUDES"));
  ++stack->loaded;
  stack->open.push_back(canonical);
  RobotModelBuilder builder("", path);
  if (EndsWith(path, ".urdf") || EndsWith(path, ".URDF") || EndsWith(path, ".xml")) {
    builder = ParseUrdf(path, options);
    const std::string sidecar = path.substr(0, path.rfind('.')) + ".trocar.yaml";
    if (IsRegularFile(sidecar)) {
      const YamlReader r = YamlReader::Load(sidecar);
      TROCAR_THROW_UNLESS(!r.root()["urdf"] && !r.root()["dh"] && !r.root()["links"] &&
                              !r.root()["joints"] && !r.root()["include"],
                          sidecar << ": a sidecar beside a URDF holds only sidecar fields (no "
                                     "urdf, dh, links, joints or include)");
      ApplySidecar(r, r.root(), &builder, options);
    }
  } else {
    TROCAR_THROW_UNLESS(EndsWith(path, ".yaml") || EndsWith(path, ".yml"),
                        path << ": unknown robot description type (expected .urdf or .yaml)");
    builder = LoadYamlDescription(path, options, stack);
  }
  stack->open.pop_back();
  return builder;
}

}  // namespace

DhTable LoadDhTable(const std::string& path) {
  const YamlReader r = YamlReader::Load(path);
  LoadOptions options;
  options.load_meshes = false;
  return ReadDhTable(r, r.Require(r.root(), "dh", ""), options);
}

std::string GainsOverlayPath(const std::string& description) {
  const std::filesystem::path p(description);
  return (p.parent_path() / (p.stem().string() + ".gains.yaml")).string();
}

RobotModelBuilder LoadRobotDescription(const std::string& path, const LoadOptions& options) {
  IncludeStack stack;
  stack.root = path;
  RobotModelBuilder builder = LoadDescription(path, options, &stack);
  // Tuned gains live in an overlay beside the robot (written by trocar tune and by teleop's
  // first-use tuning), never in the user's own file; they override the description's.
  const std::string overlay = GainsOverlayPath(path);
  if (IsRegularFile(overlay)) {
    const YamlReader r = YamlReader::Load(overlay);
    r.ExpectMap(r.root(), "", {"robot", "gains"});
    const YAML::Node gains = r.Require(r.root(), "gains", "");
    TROCAR_THROW_UNLESS(gains.IsMap(), r.Where(gains, "gains") << ": expected a mapping from "
                                                                  "controller name to 6 gains");
    for (const auto& entry : gains) {
      const std::string name = r.String(entry.first, "gains");
      const std::vector<double> values = r.Numbers(entry.second, "gains." + name);
      TROCAR_THROW_UNLESS(values.size() == 6, r.Where(entry.second, "gains." + name)
                                                  << ": expected 6 values [wx wy wz vx vy vz], got "
                                                  << values.size());
      builder.controller().gains[name] = Eigen::Map<const Eigen::VectorXd>(values.data(), 6);
    }
  }
  return builder;
}

RobotModel LoadRobot(const std::string& path, const LoadOptions& options) {
  return LoadRobotDescription(path, options).Build();
}

}  // namespace trocar::robot
