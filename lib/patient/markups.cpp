#include "patient/markups.hpp"

#include <cmath>

#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar::patient {

std::vector<Markup> LoadMarkups(const std::string& path) {
  nlohmann::json doc;
  try {
    doc = nlohmann::json::parse(ReadTextFile(path));
  } catch (const nlohmann::json::parse_error& e) {
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
    markup.type = node.value("type", std::string("Fiducial"));
    markup.name = node.value("name", "markup-" + std::to_string(m + 1));
    const std::string system = node.value("coordinateSystem", std::string("LPS"));
    TROCAR_THROW_UNLESS(system == "LPS" || system == "RAS",
                        where << ".coordinateSystem: '" << system << "' (expected LPS or RAS)");
    const std::string units = node.value("coordinateUnits", std::string("mm"));
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
      markup.labels.push_back(point.value("label", markup.name + "-" + std::to_string(i + 1)));
    }
    TROCAR_THROW_UNLESS(!markup.points.empty(), where << " ('" << markup.name << "'): no control points");
    out.push_back(std::move(markup));
  }
  TROCAR_THROW_UNLESS(!out.empty(), path << ": field 'markups' is empty");
  return out;
}

}  // namespace trocar::patient
