#include "robot/urdf_loader.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <regex>
#include <tuple>
#include <sstream>

#include <console_bridge/console.h>
#include <urdf_parser/urdf_parser.h>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/limits.hpp"
#include "common/geometry.hpp"

namespace trocar::robot {
namespace {

// urdfdom reports problems through console_bridge; collect them to put into our exception.
class CapturingHandler : public console_bridge::OutputHandler {
 public:
  void log(const std::string& text, console_bridge::LogLevel level, const char*, int) override {
    if (level >= console_bridge::CONSOLE_BRIDGE_LOG_WARN) {
      messages_ += (messages_.empty() ? "" : "; ") + text;
    }
  }
  const std::string& messages() const { return messages_; }

 private:
  std::string messages_;
};

std::mutex& ParserMutex() {
  static std::mutex mutex;
  return mutex;
}

Eigen::Isometry3d ToIsometry(const urdf::Pose& pose) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() << pose.position.x, pose.position.y, pose.position.z;
  X.linear() = Eigen::Quaterniond(pose.rotation.w, pose.rotation.x, pose.rotation.y,
                                  pose.rotation.z)
                   .normalized()
                   .toRotationMatrix();
  return X;
}

std::vector<std::string> SplitPath(const char* text) {
  std::vector<std::string> out;
  if (text == nullptr) return out;
  std::stringstream stream(text);
  std::string item;
  while (std::getline(stream, item, ':')) {
    if (!item.empty()) out.push_back(item);
  }
  return out;
}

// What the XML holds, scanned before urdfdom sees it: urdfdom's XML parser (TinyXML) recurses
// once per nesting level, so a file nested tens of thousands of elements deep overflows the
// stack; and urdfdom drops every <collision> (or <visual>) of a link when one of them is
// malformed, without failing. The scan bounds the depth and counts each link's geometry
// elements, to compare with what urdfdom returns. Comments, CDATA, processing instructions and
// declarations are skipped; quoted attribute values may hold '>'.
struct XmlCensus {
  std::map<std::string, int> collisions, visuals;  // per link name (as written)
};

XmlCensus ScanUrdfXml(const std::string& xml, const std::string& path) {
  XmlCensus census;
  const int max_depth = Limits().max_xml_depth;
  std::vector<std::string> stack;
  std::vector<std::string> link_names;  // name attribute of each open element
  std::size_t at = 0;
  // TinyXML (under urdfdom) reads past the end of a document that stops inside a tag, an
  // attribute value, a comment or a CDATA section (a heap over-read found by fuzzing): such a
  // document is refused here, naming the line where the unfinished construct starts.
  auto line_of = [&](std::size_t offset) {
    return 1 + std::count(xml.begin(), xml.begin() + static_cast<std::ptrdiff_t>(offset), '\n');
  };
  auto skip_past = [&](const char* end) {
    const std::size_t found = xml.find(end, at);
    TROCAR_THROW_UNLESS(found != std::string::npos,
                        path << ":" << line_of(at) << ": not a valid URDF: '"
                             << xml.substr(at, std::min<std::size_t>(9, xml.size() - at))
                             << "' is never closed by '" << end << "' (the file ends first)");
    at = found + std::strlen(end);
  };
  while ((at = xml.find('<', at)) != std::string::npos) {
    if (xml.compare(at, 4, "<!--") == 0) { skip_past("-->"); continue; }
    if (xml.compare(at, 9, "<![CDATA[") == 0) { skip_past("]]>"); continue; }
    if (xml.compare(at, 2, "<?") == 0) { skip_past("?>"); continue; }
    if (xml.compare(at, 2, "<!") == 0) {  // <!DOCTYPE ...[ ... ]>
      const std::size_t bracket = xml.find('[', at), close = xml.find('>', at);
      if (bracket != std::string::npos && bracket < close) {
        at = bracket;
        skip_past("]");
      }
      skip_past(">");
      continue;
    }
    // A tag: to its '>' outside quotes.
    std::size_t end = at + 1;
    char quote = 0;
    for (; end < xml.size(); ++end) {
      const char ch = xml[end];
      if (quote != 0) {
        if (ch == quote) quote = 0;
      } else if (ch == '"' || ch == '\'') {
        quote = ch;
      } else if (ch == '>') {
        break;
      }
    }
    TROCAR_THROW_UNLESS(end < xml.size(),
                        path << ":" << line_of(at) << ": not a valid URDF: the tag '"
                             << xml.substr(at, std::min<std::size_t>(24, xml.size() - at))
                             << "' is never closed"
                             << (quote != 0 ? " (an attribute value is still open)" : "")
                             << " (the file ends first)");
    const std::string tag = xml.substr(at + 1, end - at - 1);
    at = end + 1;
    if (!tag.empty() && tag[0] == '/') {
      if (!stack.empty()) {
        stack.pop_back();
        link_names.pop_back();
      }
      continue;
    }
    const bool self_closing = !tag.empty() && tag.back() == '/';
    std::size_t name_end = 0;
    while (name_end < tag.size() && !std::isspace(static_cast<unsigned char>(tag[name_end])) &&
           tag[name_end] != '/') {
      ++name_end;
    }
    const std::string element = tag.substr(0, name_end);
    std::string name_attribute;
    {
      static const std::regex kName("(^|\\s)name\\s*=\\s*(\"([^\"]*)\"|'([^']*)')");
      std::smatch m;
      const std::string attributes = tag.substr(name_end);
      if (std::regex_search(attributes, m, kName)) {
        name_attribute = m[3].matched ? m[3].str() : m[4].str();
      }
    }
    if (element == "origin") {
      // urdfdom turns rpy into a quaternion (1e308 rad becomes some finite rotation) and takes
      // any xyz: the values are checked as written (issue #44, item 3).
      static const std::regex kVector("(^|\\s)(rpy|xyz)\\s*=\\s*(\"([^\"]*)\"|'([^']*)')");
      const std::string attributes = tag.substr(name_end);
      for (auto it = std::sregex_iterator(attributes.begin(), attributes.end(), kVector);
           it != std::sregex_iterator(); ++it) {
        const std::string key = (*it)[2].str();
        const std::string value = (*it)[4].matched ? (*it)[4].str() : (*it)[5].str();
        std::istringstream numbers(value);
        double x = 0.0;
        while (numbers >> x) {
          const double bound = key == "rpy" ? 2 * M_PI + 1e-9 : 100.0;
          TROCAR_THROW_UNLESS(std::isfinite(x) && std::abs(x) <= bound,
                              path << ":" << line_of(at) << ": <origin " << key << "=\"" << value
                                   << "\">: " << x << " is outside "
                                   << (key == "rpy" ? "one turn either way (|angle| <= 2 pi rad)"
                                                    : "100 m either way"));
        }
      }
    }
    if (stack.size() == 2 && stack[0] == "robot" && stack[1] == "link") {
      if (element == "collision") ++census.collisions[link_names[1]];
      if (element == "visual") ++census.visuals[link_names[1]];
    }
    if (self_closing) continue;
    stack.push_back(element);
    link_names.push_back(name_attribute);
    TROCAR_THROW_UNLESS(static_cast<int>(stack.size()) <= max_depth,
                        path << ": XML elements nested more than " << max_depth << " deep (at <"
                             << element << "> near byte " << at << ") "
                             << LimitHint(static_cast<std::uint64_t>(max_depth),
                                          "TROCAR_MAX_XML_DEPTH"));
  }
  return census;
}

}  // namespace

std::string ResolveMeshPath(const std::string& uri, const std::string& description_file,
                            const std::vector<std::string>& package_paths) {
  namespace fs = std::filesystem;
  const std::string base_dir = ParentDirectory(description_file);
  const std::string package_prefix = "package://";
  const std::string file_prefix = "file://";
  if (uri.rfind(file_prefix, 0) == 0) return uri.substr(file_prefix.size());
  if (uri.rfind(package_prefix, 0) != 0) return JoinPath(base_dir, uri);
  const std::string rest = uri.substr(package_prefix.size());
  const auto slash = rest.find('/');
  TROCAR_THROW_UNLESS(slash != std::string::npos && slash > 0,
                      description_file << ": mesh '" << uri
                                       << "': expected package://<package>/<path>");
  const std::string package = rest.substr(0, slash);
  const std::string relative = rest.substr(slash + 1);
  std::vector<std::string> candidates;
  // 1. A folder named like the package among the description's ancestors (a package's own URDF).
  std::error_code ec;
  for (fs::path dir = fs::absolute(base_dir, ec); !dir.empty(); dir = dir.parent_path()) {
    if (dir.filename() == package) candidates.push_back(dir.string());
    candidates.push_back((dir / package).string());
    if (dir == dir.root_path()) break;
  }
  // 2. Explicit package paths, then TROCAR_PACKAGE_PATH and ROS_PACKAGE_PATH.
  std::vector<std::string> roots = package_paths;
  for (const char* var : {"TROCAR_PACKAGE_PATH", "ROS_PACKAGE_PATH"}) {
    for (const std::string& p : SplitPath(std::getenv(var))) roots.push_back(p);
  }
  for (const std::string& root : roots) {
    if (fs::path(root).filename() == package) candidates.push_back(root);
    candidates.push_back((fs::path(root) / package).string());
  }
  for (const std::string& dir : candidates) {
    const std::string path = JoinPath(dir, relative);
    if (IsRegularFile(path)) return path;
  }
  TROCAR_THROW(description_file << ": mesh '" << uri << "': package '" << package
                                << "' not found beside the file, in TROCAR_PACKAGE_PATH or in "
                                   "ROS_PACKAGE_PATH");
}

RobotModelBuilder ParseUrdf(const std::string& path, const LoadOptions& options) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": URDF file not found");
  const std::string xml = ReadTextFile(path);
  const XmlCensus census = ScanUrdfXml(xml, path);
  urdf::ModelInterfaceSharedPtr urdf_model;
  std::string parser_messages;
  {
    std::lock_guard<std::mutex> lock(ParserMutex());
    CapturingHandler handler;
    console_bridge::useOutputHandler(&handler);
    try {
      urdf_model = urdf::parseURDF(xml);
    } catch (const std::exception& e) {
      parser_messages = e.what();
    }
    console_bridge::restorePreviousOutputHandler();
    if (parser_messages.empty()) parser_messages = handler.messages();
  }
  // urdfdom drops the whole <collision> (or <visual>) list of a link when one element of it
  // fails to parse, and still returns the model: a robot silently without collision shapes.
  if (urdf_model != nullptr) {
    for (const auto& [name, link] : urdf_model->links_) {
      for (const auto& [kind, counts, parsed] :
           {std::make_tuple("collision", &census.collisions, link->collision_array.size()),
            std::make_tuple("visual", &census.visuals, link->visual_array.size())}) {
        const auto it = counts->find(name);
        if (it == counts->end()) continue;  // a name written with entities: not comparable
        TROCAR_THROW_UNLESS(
            static_cast<std::size_t>(it->second) <= parsed,
            path << ": link '" << name << "': " << it->second << " <" << kind
                 << "> element(s) in the file, but the URDF parser could read only " << parsed
                 << ": one of them is malformed (e.g. a box size that is not three numbers, a "
                    "missing <geometry>)"
                 << (parser_messages.empty() ? std::string() : ": " + parser_messages));
      }
    }
  }
  TROCAR_THROW_UNLESS(urdf_model != nullptr,
                      path << ": not a valid URDF: "
                           << (parser_messages.empty() ? "parser gave no reason" : parser_messages));

  RobotModelBuilder builder(urdf_model->getName(), path);
  std::map<std::string, std::shared_ptr<const TriangleMesh>> mesh_cache;

  auto convert_geometry = [&](const std::string& where, const urdf::GeometrySharedPtr& geometry,
                              const urdf::Pose& origin) {
    TROCAR_THROW_UNLESS(geometry != nullptr, where << ": has no <geometry>");
    Geometry g;
    g.X_LG = ToIsometry(origin);
    switch (geometry->type) {
      case urdf::Geometry::SPHERE: {
        g.shape = Geometry::Shape::kSphere;
        g.size[0] = static_cast<const urdf::Sphere&>(*geometry).radius;
        break;
      }
      case urdf::Geometry::BOX: {
        const auto& box = static_cast<const urdf::Box&>(*geometry);
        g.shape = Geometry::Shape::kBox;
        g.size << box.dim.x, box.dim.y, box.dim.z;
        break;
      }
      case urdf::Geometry::CYLINDER: {
        const auto& cylinder = static_cast<const urdf::Cylinder&>(*geometry);
        g.shape = Geometry::Shape::kCylinder;
        g.size << cylinder.radius, cylinder.length, 0.0;
        break;
      }
      case urdf::Geometry::MESH: {
        const auto& mesh = static_cast<const urdf::Mesh&>(*geometry);
        g.shape = Geometry::Shape::kMesh;
        g.mesh_scale << mesh.scale.x, mesh.scale.y, mesh.scale.z;
        g.mesh_file = ResolveMeshPath(mesh.filename, path, options.package_paths);
        TROCAR_THROW_UNLESS(IsRegularFile(g.mesh_file), where << ": mesh file '" << mesh.filename
                                                              << "' not found (looked for "
                                                              << g.mesh_file << ")");
        if (options.load_meshes) {
          std::ostringstream key;
          key << g.mesh_file << '|' << g.mesh_scale.transpose();
          auto& cached = mesh_cache[key.str()];
          if (!cached) {
            try {
              cached = LoadMesh(g.mesh_file, g.mesh_scale);
            } catch (const Error& e) {
              TROCAR_THROW(where << ": " << e.what());
            }
          }
          g.mesh = cached;
        }
        break;
      }
    }
    return g;
  };

  // Links first (joints refer to them by name); keep a stable order: urdfdom's map order.
  for (const auto& [name, link] : urdf_model->links_) {
    RobotModelBuilder::LinkSpec& spec = builder.AddLink(name);
    for (std::size_t i = 0; i < link->visual_array.size(); ++i) {
      const auto& visual = link->visual_array[i];
      const std::string where = path + ": link '" + name + "' visual " + std::to_string(i);
      Geometry g = convert_geometry(where, visual->geometry, visual->origin);
      if (visual->material) {
        const urdf::Color& c = visual->material->color;
        g.rgba << c.r, c.g, c.b, c.a;
      }
      spec.visuals.push_back(std::move(g));
    }
    for (std::size_t i = 0; i < link->collision_array.size(); ++i) {
      const auto& collision = link->collision_array[i];
      const std::string where = path + ": link '" + name + "' collision " + std::to_string(i);
      spec.collisions.push_back(convert_geometry(where, collision->geometry, collision->origin));
    }
  }
  for (const auto& [name, joint] : urdf_model->joints_) {
    const std::string where = path + ": joint '" + name + "'";
    RobotModelBuilder::JointSpec& spec = builder.AddJoint(name);
    spec.parent = joint->parent_link_name;
    spec.child = joint->child_link_name;
    spec.X_PJ = ToIsometry(joint->parent_to_joint_origin_transform);
    spec.axis << joint->axis.x, joint->axis.y, joint->axis.z;
    switch (joint->type) {
      case urdf::Joint::FIXED: spec.type = JointType::kFixed; break;
      case urdf::Joint::REVOLUTE:
      case urdf::Joint::CONTINUOUS: spec.type = JointType::kRevolute; break;
      case urdf::Joint::PRISMATIC: spec.type = JointType::kPrismatic; break;
      default:
        TROCAR_THROW(where << ": joint type " << joint->type
                           << " (floating or planar) is not supported; use revolute, continuous, "
                              "prismatic or fixed");
    }
    if (joint->limits && spec.type != JointType::kFixed) {
      if (joint->type != urdf::Joint::CONTINUOUS) {
        spec.limits.lower = joint->limits->lower;
        spec.limits.upper = joint->limits->upper;
      }
      // URDF requires velocity; 0 is the common way of leaving it unspecified.
      if (joint->limits->velocity != 0.0) spec.limits.velocity = joint->limits->velocity;
      if (joint->limits->effort != 0.0) spec.limits.effort = joint->limits->effort;
    }
    if (joint->mimic) {
      spec.mimic_master = joint->mimic->joint_name;
      spec.mimic_multiplier = joint->mimic->multiplier;
      spec.mimic_offset = joint->mimic->offset;
    }
    TROCAR_THROW_UNLESS(spec.X_PJ.matrix().allFinite(), where << ": <origin> is not finite");
  }
  return builder;
}

}  // namespace trocar::robot
