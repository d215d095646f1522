#include "patient/markups.hpp"

#include <cmath>

#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/json_util.hpp"
#include "common/file_util.hpp"

namespace trocar::patient {

namespace {

// node[key] as a string, `fallback` when absent. @throws naming the field when it is not text.
std::string Text(const nlohmann::json& node, const char* key, const std::string& fallback,
                 const std::string& where) {
  if (!node.contains(key) || node[key].is_null()) return fallback;
  TROCAR_THROW_UNLESS(node[key].is_string(), where << "." << key << ": expected a string, got "
                                                   << node[key].dump().substr(0, 60));
  return node[key].get<std::string>();
}

}  // namespace

std::vector<Markup> LoadMarkups(const std::string& path) {
  nlohmann::json doc;
  try {
    doc = ReadJsonFile(path);
  } catch (const nlohmann::json::exception& e) {
    // Syntax errors, and numbers out of range (1e400) which the parser refuses with their own
    // exception type.
    TROCAR_THROW(path << ": not valid JSON: " << e.what());
  }
  TROCAR_THROW_UNLESS(doc.is_object() && doc.contains("markups") && doc["markups"].is_array(),
                      path << ": missing field 'markups' (expected a 3D Slicer .mrk.json file)");
  std::vector<Markup> out;
  for (std::size_t m = 0; m < doc["markups"].size(); ++m) {
    const nlohmann::json& node = doc["markups"][m];
    const std::string where = path + ": markups[" + std::to_string(m) + "]";
    TROCAR_THROW_UNLESS(node.is_object(), where << ": expected an object");
    Markup markup;
    markup.type = Text(node, "type", "Fiducial", where);
    markup.name = Text(node, "name", "markup-" + std::to_string(m + 1), where);
    const std::string system = Text(node, "coordinateSystem", "LPS", where);
    TROCAR_THROW_UNLESS(system == "LPS" || system == "RAS",
                        where << ".coordinateSystem: '" << system << "' (expected LPS or RAS)");
    const std::string units = Text(node, "coordinateUnits", "mm", where);
    TROCAR_THROW_UNLESS(units == "mm" || units == "m",
                        where << ".coordinateUnits: '" << units << "' (expected mm or m)");
    const double scale = units == "mm" ? 1e-3 : 1.0;
    const Eigen::Vector3d to_lps(system == "RAS" ? -1.0 : 1.0, system == "RAS" ? -1.0 : 1.0, 1.0);
    TROCAR_THROW_UNLESS(node.contains("controlPoints") && node["controlPoints"].is_array(),
                        where << ": missing field 'controlPoints'");
    const auto& points = node["controlPoints"];
    for (std::size_t i = 0; i < points.size(); ++i) {
      const std::string p_where = where + ".controlPoints[" + std::to_string(i) + "]";
      const auto& point = points[i];
      TROCAR_THROW_UNLESS(point.is_object() && point.contains("position") &&
                              point["position"].is_array() && point["position"].size() == 3,
                          p_where << ": missing field 'position' (three numbers)");
      Eigen::Vector3d p;
      for (int a = 0; a < 3; ++a) {
        TROCAR_THROW_UNLESS(point["position"][a].is_number(),
                            p_where << ".position[" << a << "]: expected a number");
        p[a] = point["position"][a].get<double>();
      }
      TROCAR_THROW_UNLESS(p.allFinite(), p_where << ".position: not finite");
      markup.points.push_back(to_lps.asDiagonal() * p * scale);
      markup.labels.push_back(Text(point, "label", markup.name + "-" + std::to_string(i + 1), p_where));
      if (point.contains("orientation")) {
        const auto& o = point["orientation"];
        TROCAR_THROW_UNLESS(o.is_array() && o.size() == 9,
                            p_where << ".orientation: expected 9 numbers (a 3x3 matrix)");
        Eigen::Vector3d z;
        for (int r = 0; r < 3; ++r) {
          TROCAR_THROW_UNLESS(o[3 * r + 2].is_number(), p_where << ".orientation: expected numbers");
          z[r] = o[3 * r + 2].get<double>();
        }
        z = to_lps.asDiagonal() * z;
        TROCAR_THROW_UNLESS(z.allFinite() && z.norm() > 1e-9,
                            p_where << ".orientation: the normal (z column) is zero or not finite");
        TROCAR_THROW_UNLESS(markup.normals.size() == i,
                            p_where << ".orientation: given for some control points only");
        markup.normals.push_back(z.normalized());
      }
    }
    TROCAR_THROW_UNLESS(!markup.points.empty(), where << " ('" << markup.name << "'): no control points");
    TROCAR_THROW_UNLESS(markup.normals.empty() || markup.normals.size() == markup.points.size(),
                        where << ": orientation given for some control points only");
    out.push_back(std::move(markup));
  }
  TROCAR_THROW_UNLESS(!out.empty(), path << ": field 'markups' is empty");
  return out;
}

void WriteMarkups(const std::vector<Markup>& markups, const std::string& path) {
  nlohmann::json list = nlohmann::json::array();
  for (const Markup& m : markups) {
    TROCAR_THROW_UNLESS(m.normals.empty() || m.normals.size() == m.points.size(),
                        path << ": markup '" << m.name << "' has " << m.normals.size()
                             << " normals for " << m.points.size() << " points");
    nlohmann::json points = nlohmann::json::array();
    for (std::size_t i = 0; i < m.points.size(); ++i) {
      const Eigen::Vector3d mm = m.points[i] * 1e3;
      TROCAR_THROW_UNLESS(mm.allFinite(), path << ": markup '" << m.name << "' point " << i << " is not finite");
      nlohmann::json point = {{"id", std::to_string(i + 1)},
                              {"label", i < m.labels.size() ? m.labels[i] : m.name + "-" + std::to_string(i + 1)},
                              {"position", {mm.x(), mm.y(), mm.z()}},
                              {"positionStatus", "defined"}};
      if (!m.normals.empty()) {
        // An orthonormal frame whose z column is the normal (row-major, as Slicer stores it).
        const Eigen::Vector3d z = m.normals[i].normalized();
        const Eigen::Vector3d x = z.unitOrthogonal(), y = z.cross(x);
        point["orientation"] = {x.x(), y.x(), z.x(), x.y(), y.y(), z.y(), x.z(), y.z(), z.z()};
      }
      points.push_back(point);
    }
    list.push_back({{"type", m.type.empty() ? "Fiducial" : m.type},
                    {"name", m.name},
                    {"coordinateSystem", "LPS"},
                    {"coordinateUnits", "mm"},
                    {"controlPoints", points}});
  }
  const nlohmann::json doc = {
      {"@schema",
       "https://raw.githubusercontent.com/slicer/slicer/main/Modules/Loadable/Markups/Resources/"
       "Schema/markups-schema-v1.0.3.json#"},
      {"markups", list}};
  WriteFileAtomically(path, doc.dump(2));
}

}  // namespace trocar::patient
