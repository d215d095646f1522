#include "bench/spec.hpp"

#include <algorithm>
#include <filesystem>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/yaml_util.hpp"
#include "motion/motion.hpp"
#include "port_placement/optimizer.hpp"

namespace trocar::planners {

namespace {

std::string Join(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

std::string Resolve(const std::string& spec_dir, const std::string& path) {
  if (std::filesystem::path(path).is_absolute()) return path;
  const std::string beside = JoinPath(spec_dir, path);
  if (std::filesystem::exists(beside)) return beside;
  return path;
}

std::vector<unsigned> Seeds(const YamlReader& r, const YAML::Node& node, const std::string& path) {
  std::vector<unsigned> seeds;
  const std::vector<double> numbers = r.Numbers(node, path);
  TROCAR_THROW_UNLESS(!numbers.empty(), r.Where(node, path) << ": expected at least one seed");
  for (double s : numbers) {
    TROCAR_THROW_UNLESS(s >= 1 && s <= 4e9 && s == std::floor(s),
                        r.Where(node, path) << ": seed " << s << ": expected a whole number >= 1");
    seeds.push_back(static_cast<unsigned>(s));
  }
  return seeds;
}

int Count(const YamlReader& r, const YAML::Node& map, const std::string& key,
          const std::string& path, int fallback, int lo, int hi) {
  const double v = r.NumberOr(map, key, path, fallback);
  TROCAR_THROW_UNLESS(v >= lo && v <= hi && v == std::floor(v),
                      r.Where(map[key] ? map[key] : map, path + "." + key)
                          << ": " << v << ": expected a whole number in " << lo << ".." << hi);
  return static_cast<int>(v);
}

}  // namespace

std::string BenchSpec::Canonical() const {
  std::ostringstream s;
  s.precision(17);
  s << "name=" << name << "\nrobot=" << robot << "\narms=" << Join(arms)
    << "\nsamples_per_target=" << samples_per_target << "\npatients=" << Join(patients)
    << "\nalgorithms=";
  for (const auto& a : algorithms) s << a.name() << ",";
  s << "\nevaluations=" << evaluations << "\npolish_evaluations=" << polish_evaluations
    << "\ntop_k=" << top_k << "\nplacement_seeds=";
  for (unsigned v : placement_seeds) s << v << ",";
  s << "\nplanners=" << Join(planners) << "\ntime_limit=" << time_limit << "\nmotion_seeds=";
  for (unsigned v : motion_seeds) s << v << ",";
  s << "\n";
  return s.str();
}

BenchSpec ReadBenchSpec(const std::string& path, const std::string& default_robot) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": no such bench spec");
  const YamlReader r = YamlReader::Load(path);
  const YAML::Node& root = r.root();
  r.ExpectMap(root, "", {"name", "patients", "robot", "arms", "samples_per_target", "placement",
                         "motion", "threads"});
  const std::string dir = ParentDirectory(path);
  BenchSpec spec;
  spec.file = path;
  spec.name = root["name"] ? r.String(root["name"], "name")
                           : std::filesystem::path(path).stem().string();
  TROCAR_THROW_UNLESS(!spec.name.empty() && spec.name.find_first_of(" \t\n/") == std::string::npos,
                      r.Where(root["name"] ? root["name"] : root, "name")
                          << ": '" << spec.name << "': expected a name without spaces or slashes");
  const YAML::Node patients = r.Require(root, "patients", "");
  for (const std::string& p : r.Strings(patients, "patients")) {
    const std::string resolved = Resolve(dir, p);
    if (!IsRegularFile(JoinPath(resolved, "patient.yaml"))) {
      // The valid names: the case folders beside the one named (its parent folder).
      std::string parent = ParentDirectory(resolved);
      if (parent.empty()) parent = ".";
      std::vector<std::string> cases;
      std::error_code ec;
      for (const auto& entry : std::filesystem::directory_iterator(parent, ec)) {
        if (IsRegularFile(JoinPath(entry.path().string(), "patient.yaml")))
          cases.push_back(entry.path().filename().string());
      }
      std::sort(cases.begin(), cases.end());
      TROCAR_THROW(r.Where(patients, "patients")
                   << ": unknown patient '" << p << "': no case folder with patient.yaml there ("
                   << (cases.empty() ? "no cases in " + parent
                                     : "cases in " + parent + ": " + Join(cases))
                   << ")");
    }
    spec.patients.push_back(resolved);
  }
  TROCAR_THROW_UNLESS(!spec.patients.empty(), r.Where(patients, "patients") << ": no patient");
  const std::string robot = root["robot"] ? r.String(root["robot"], "robot") : default_robot;
  spec.robot = root["robot"] ? Resolve(dir, robot) : robot;
  TROCAR_THROW_UNLESS(IsRegularFile(spec.robot),
                      r.Where(root["robot"] ? root["robot"] : root, "robot")
                          << ": " << robot << ": no such robot description");
  if (root["arms"]) spec.arms = r.Strings(root["arms"], "arms");
  spec.samples_per_target = Count(r, root, "samples_per_target", "", 4, 1, 1000);
  spec.threads = Count(r, root, "threads", "", 0, 0, 1024);

  const YAML::Node placement = r.Require(root, "placement", "");
  r.ExpectMap(placement, "placement",
              {"algorithms", "evaluations", "polish_evaluations", "top_k", "seeds"});
  const std::vector<std::string> globals = GlobalAlgorithms(), locals = LocalAlgorithms();
  const YAML::Node algorithms = r.Require(placement, "algorithms", "placement");
  for (const std::string& a : r.Strings(algorithms, "placement.algorithms")) {
    BenchAlgorithm algorithm;
    const auto plus = a.find('+');
    algorithm.global = a.substr(0, plus);
    algorithm.local = plus == std::string::npos ? "none" : a.substr(plus + 1);
    TROCAR_THROW_UNLESS(
        std::count(globals.begin(), globals.end(), algorithm.global) &&
            std::count(locals.begin(), locals.end(), algorithm.local),
        r.Where(algorithms, "placement.algorithms")
            << ": unknown port-placement algorithm '" << a << "' (expected GLOBAL or GLOBAL+LOCAL; "
            << "global: " << Join(globals) << "; local: " << Join(locals) << ")");
    spec.algorithms.push_back(algorithm);
  }
  TROCAR_THROW_UNLESS(!spec.algorithms.empty(),
                      r.Where(algorithms, "placement.algorithms") << ": no algorithm");
  spec.evaluations = Count(r, placement, "evaluations", "placement", 300, 1, 10000000);
  spec.polish_evaluations = Count(r, placement, "polish_evaluations", "placement", 30, 0, 1000000);
  spec.top_k = Count(r, placement, "top_k", "placement", 1, 1, 100);
  if (placement["seeds"]) spec.placement_seeds = Seeds(r, placement["seeds"], "placement.seeds");

  const YAML::Node motion = r.Require(root, "motion", "");
  r.ExpectMap(motion, "motion", {"planners", "time_limit", "seeds"});
  const YAML::Node planners = r.Require(motion, "planners", "motion");
  const std::vector<std::string> valid = MotionPlanners();
  for (const std::string& p : r.Strings(planners, "motion.planners")) {
    TROCAR_THROW_UNLESS(std::count(valid.begin(), valid.end(), p),
                        r.Where(planners, "motion.planners") << ": unknown planner '" << p
                                                             << "' (valid: " << Join(valid) << ")");
    spec.planners.push_back(p);
  }
  TROCAR_THROW_UNLESS(!spec.planners.empty(),
                      r.Where(planners, "motion.planners") << ": no planner");
  spec.time_limit = r.NumberOr(motion, "time_limit", "motion", 1.0);
  TROCAR_THROW_UNLESS(spec.time_limit > 0 && spec.time_limit <= 3600,
                      r.Where(motion["time_limit"], "motion.time_limit")
                          << ": " << spec.time_limit << " s: expected (0, 3600]");
  if (motion["seeds"]) spec.motion_seeds = Seeds(r, motion["seeds"], "motion.seeds");
  // Runs are keyed by patient (folder name), algorithm, planner and seed: a name given twice
  // would be one run twice.
  auto unique = [&](std::vector<std::string> names, const YAML::Node& node, const std::string& field) {
    std::sort(names.begin(), names.end());
    const auto twice = std::adjacent_find(names.begin(), names.end());
    TROCAR_THROW_UNLESS(twice == names.end(), r.Where(node, field) << ": '" << *twice
                                                                   << "' given twice");
  };
  std::vector<std::string> names;
  for (const auto& p : spec.patients)
    names.push_back(std::filesystem::path(p).lexically_normal().filename().string());
  unique(names, patients, "patients");
  names.clear();
  for (const auto& a : spec.algorithms) names.push_back(a.name());
  unique(names, algorithms, "placement.algorithms");
  unique(spec.planners, planners, "motion.planners");
  auto seed_names = [](const std::vector<unsigned>& seeds) {
    std::vector<std::string> out;
    for (unsigned v : seeds) out.push_back(std::to_string(v));
    return out;
  };
  unique(seed_names(spec.placement_seeds), placement["seeds"] ? placement["seeds"] : placement,
         "placement.seeds");
  unique(seed_names(spec.motion_seeds), motion["seeds"] ? motion["seeds"] : motion, "motion.seeds");
  return spec;
}

}  // namespace trocar::planners
