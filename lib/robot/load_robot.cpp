#include "robot/load_robot.hpp"

#include <filesystem>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/geometry.hpp"
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
  limits->lower = r.NumberOr(node, "lower", path, limits->lower);
  limits->upper = r.NumberOr(node, "upper", path, limits->upper);
  limits->velocity = r.NumberOr(node, "velocity", path, limits->velocity);
  limits->acceleration = r.NumberOr(node, "acceleration", path, limits->acceleration);
  limits->effort = r.NumberOr(node, "effort", path, limits->effort);
  TROCAR_THROW_UNLESS(limits->lower <= limits->upper,
                      r.Where(node, path) << ": lower limit " << limits->lower
                                          << " > upper limit " << limits->upper);
  for (const char* key : {"velocity", "acceleration"}) {
    if (node[key]) {
      const double v = r.Number(node[key], path + "." + key);
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

const std::initializer_list<const char*> kSidecarKeys = {
    "name",       "tool",         "rcm",      "frames",    "active_joints", "held_joints",
    "joint_limits", "closures", "collision", "controller", "urdf",         "dh"};

// Applies the sidecar fields of `root` to `builder`.
void ApplySidecar(const YamlReader& r, const YAML::Node& root, RobotModelBuilder* builder,
                  const LoadOptions& options) {
  r.ExpectMap(root, "", kSidecarKeys);
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
  if (root["controller"]) {
    const YAML::Node node = root["controller"];
    r.ExpectMap(node, "controller", {"task_gains"});
    if (node["task_gains"]) {
      const std::vector<double> gains = r.Numbers(node["task_gains"], "controller.task_gains");
      TROCAR_THROW_UNLESS(gains.size() == 6, r.Where(node["task_gains"], "controller.task_gains")
                                                 << ": expected 6 values [wx wy wz vx vy vz], got "
                                                 << gains.size());
      builder->controller().task_gains =
          Eigen::Map<const Eigen::VectorXd>(gains.data(), static_cast<Eigen::Index>(gains.size()));
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

}  // namespace

DhTable LoadDhTable(const std::string& path) {
  const YamlReader r = YamlReader::Load(path);
  LoadOptions options;
  options.load_meshes = false;
  return ReadDhTable(r, r.Require(r.root(), "dh", ""), options);
}

RobotModel LoadRobot(const std::string& path, const LoadOptions& options) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": robot description not found");
  if (EndsWith(path, ".urdf") || EndsWith(path, ".URDF") || EndsWith(path, ".xml")) {
    RobotModelBuilder builder = ParseUrdf(path, options);
    const std::string stem = path.substr(0, path.rfind('.'));
    const std::string sidecar = stem + ".trocar.yaml";
    if (IsRegularFile(sidecar)) {
      const YamlReader r = YamlReader::Load(sidecar);
      TROCAR_THROW_UNLESS(!r.root()["urdf"] && !r.root()["dh"],
                          sidecar << ": a sidecar beside a URDF must not name 'urdf' or 'dh'");
      ApplySidecar(r, r.root(), &builder, options);
    }
    return builder.Build();
  }
  TROCAR_THROW_UNLESS(EndsWith(path, ".yaml") || EndsWith(path, ".yml"),
                      path << ": unknown robot description type (expected .urdf or .yaml)");
  const YamlReader r = YamlReader::Load(path);
  const YAML::Node& root = r.root();
  if (root["urdf"]) {
    const std::string urdf =
        JoinPath(ParentDirectory(path), r.String(root["urdf"], "urdf"));
    RobotModelBuilder builder = ParseUrdf(urdf, options);
    ApplySidecar(r, root, &builder, options);
    return builder.Build();
  }
  TROCAR_THROW_UNLESS(root["dh"], r.Where(root, "")
                                      << ": a robot YAML needs 'urdf: <file>' or a 'dh:' table");
  const DhTable table = ReadDhTable(r, root["dh"], options);
  RobotModelBuilder builder(std::filesystem::path(path).stem().string(), path);
  AddDhChain(table, &builder);
  ApplySidecar(r, root, &builder, options);
  return builder.Build();
}

}  // namespace trocar::robot
