#include "port_placement/plan_config.hpp"

#include <cmath>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/yaml_util.hpp"
#include "port_placement/score_terms.hpp"

namespace trocar::planners {

void ReadPlanConfig(const std::string& case_dir, ProblemOptions* options) {
  const std::string file = JoinPath(case_dir, "patient.yaml");
  if (!IsRegularFile(file)) return;  // ImportPatient names the missing case file
  const YamlReader y = YamlReader::Load(file);
  const YAML::Node plan = y.root()["plan"];
  if (!plan) return;
  y.ExpectMap(plan, "plan",
              {"arms", "roles", "samples_per_target", "standoff", "table_height", "weights"});
  if (plan["arms"]) options->arms = y.Strings(plan["arms"], "plan.arms");
  if (plan["roles"]) {
    const YAML::Node roles = plan["roles"];
    TROCAR_THROW_UNLESS(roles.IsMap(), y.Where(roles, "plan.roles")
                                           << ": expected a map {arm: instrument|endoscope}");
    for (const auto& kv : roles) {
      const std::string arm = y.String(kv.first, "plan.roles");
      options->roles.push_back(arm + "=" + y.String(kv.second, "plan.roles." + arm));
    }
  }
  if (plan["samples_per_target"]) {
    const double n = y.Number(plan["samples_per_target"], "plan.samples_per_target");
    TROCAR_THROW_UNLESS(n >= 1 && n <= 200 && n == std::floor(n),
                        y.Where(plan["samples_per_target"], "plan.samples_per_target")
                            << ": " << n << ", expected a whole number from 1 to 200");
    options->samples_per_target = static_cast<int>(n);
  }
  if (plan["standoff"]) {
    const double s = y.Number(plan["standoff"], "plan.standoff");
    TROCAR_THROW_UNLESS(s >= 0 && s <= 0.05, y.Where(plan["standoff"], "plan.standoff")
                                                 << ": " << s << " m, expected 0 to 0.05");
    options->standoff = s;
  }
  if (const YAML::Node t = plan["table_height"]) {
    // The heights the search may set the table's top to, or `fixed`: the case's table.
    if (t.IsScalar() && t.as<std::string>() == "fixed") {
      options->table_height_min = options->table_height_max = std::nan("");
    } else {
      const std::vector<double> range = y.Numbers(t, "plan.table_height");
      TROCAR_THROW_UNLESS(
          range.size() == 2 && range[0] >= 0.3 && range[0] <= range[1] && range[1] <= 1.5,
          y.Where(t, "plan.table_height")
              << ": expected [lowest, highest] in m with 0.3 <= lowest <= highest "
                 "<= 1.5, or fixed (the case's table)");
      options->table_height_min = range[0];
      options->table_height_max = range[1];
    }
  }
  if (plan["weights"]) {
    const YAML::Node w = plan["weights"];
    // One weight per score term, named as the term (score_terms.hpp).
    std::vector<std::string> names;
    for (const ScoreTermDefinition& term : ScoreTermDefinitions()) names.push_back(term.name);
    y.ExpectMap(w, "plan.weights", names);
    ScoreWeights& sw = options->weights;
    auto read = [&](const char* key, double* value) {
      if (!w[key]) return;
      const double v = y.Number(w[key], std::string("plan.weights.") + key);
      TROCAR_THROW_UNLESS(v >= 0 && v <= 100, y.Where(w[key], std::string("plan.weights.") + key)
                                                  << ": " << v
                                                  << ", expected a weight from 0 to 100");
      *value = v;
    };
    for (const ScoreTermDefinition& term : ScoreTermDefinitions())
      read(term.name, &(sw.*term.weight));
    TROCAR_THROW_UNLESS(sw.sum() > 0, y.Where(w, "plan.weights") << ": every weight is 0");
  }
}

}  // namespace trocar::planners
