#include "bench/runner.hpp"

// The C API only (OpenMPI otherwise pulls in its deprecated C++ bindings).
#define OMPI_SKIP_MPICXX 1
#define MPICH_SKIP_MPICXX 1
#include <mpi.h>
#include <omp.h>

#include <atomic>

#include <chrono>
#include <cstdlib>
#include <cmath>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "bench/database.hpp"
#include "common/error.hpp"
#include "common/json_util.hpp"
#include "motion/motion.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/optimizer.hpp"
#include "robot/load_robot.hpp"

namespace trocar::planners {

namespace {

using Clock = std::chrono::steady_clock;

// Run properties, named as OMPL's benchmark names them where they mean the same.
const std::vector<RunProperty>& PlacementProperties() {
  static const std::vector<RunProperty> p = {
      {"time", "REAL"},          {"solved", "BOOLEAN"},        {"score", "REAL"},
      {"rank score", "REAL"},    {"coverage", "REAL"},         {"evaluations", "INTEGER"},
      {"seed", "INTEGER"},       {"placed", "BOOLEAN"},        {"collisions", "INTEGER"},
      {"dexterity score", "REAL"},  {"approach score", "REAL"},  {"triangulation score", "REAL"},
      {"endoscope score", "REAL"},  {"spacing score", "REAL"},
      {"clearance arm arm score", "REAL"}, {"clearance arm patient score", "REAL"},
      {"clearance instrument rib score", "REAL"}};
  return p;
}

const std::vector<RunProperty>& MotionProperties() {
  static const std::vector<RunProperty> p = {
      {"time", "REAL"},
      {"solved", "BOOLEAN"},
      {"status", "ENUM"},
      {"approximate solution", "BOOLEAN"},
      {"correct solution", "BOOLEAN"},
      {"solution length", "REAL"},
      {"solution clearance", "REAL"},
      {"solution segments", "INTEGER"},
      {"simplification time", "REAL"},
      {"simplified solution length", "REAL"},
      {"simplified solution clearance", "REAL"},
      {"simplified solution segments", "INTEGER"},
      {"simplified correct solution", "BOOLEAN"},
      {"graph states", "INTEGER"},
      {"graph motions", "INTEGER"},
      {"seed", "INTEGER"},
      {"arm", "INTEGER"},
      {"target sample", "INTEGER"},
      {"tip path length", "REAL"},
      {"rechecked states", "INTEGER"}};
  return p;
}

std::string PatientName(const std::string& dir) {
  std::string d = dir;
  while (d.size() > 1 && d.back() == '/') d.pop_back();
  const auto slash = d.find_last_of('/');
  return slash == std::string::npos ? d : d.substr(slash + 1);
}

struct PatientSetup {
  std::string name;
  std::shared_ptr<const patient::PatientModel> model;
  std::unique_ptr<PortPlacementProblem> problem;
};

struct PlacementRun {
  int patient = 0, algorithm = 0;
  unsigned seed = 1;
  std::string key;
};

struct MotionExperiment {
  int patient = 0, algorithm = 0;
  int experiment_id = 0;
  bool placed = false;
  std::string why_not;
  std::unique_ptr<MotionProblem> problem;
  std::vector<int> instruments;
};

struct MotionRun {
  int experiment = 0;  // index into the motion experiments
  int planner = 0;     // index into spec.planners
  unsigned seed = 1;
  int arm = 0, sample = 0;
  std::string key;
};

std::string PlannerSettings(const std::string& planner, const BenchSpec& spec) {
  std::ostringstream s;
  s << "time_limit REAL = " << spec.time_limit << "\n;check_step REAL = 0.01\n;recheck_step "
    << "REAL = 0.002\n;prismatic_weight REAL = 10\n;simplify BOOLEAN = 1\n;";
  (void)planner;
  return s.str();
}

// MPI (OpenMPI from Debian): active when the process was started by mpirun with more than one
// rank. Rank 0 owns the database; every rank computes its share of the runs (run i of the ones
// to do goes to rank i mod N) and sends each result to rank 0 as one message (JSON text).
struct Mpi {
  int rank = 0, size = 1;
  bool active = false;
  static constexpr int kResult = 1, kDone = 2, kError = 3;
};

Mpi StartMpi() {
  Mpi mpi;
  const char* size = std::getenv("OMPI_COMM_WORLD_SIZE");
  if (!size || std::atoi(size) < 2) return mpi;
  int initialized = 0;
  MPI_Initialized(&initialized);
  if (!initialized) {
    int provided = 0;
    MPI_Init_thread(nullptr, nullptr, MPI_THREAD_SERIALIZED, &provided);
    TROCAR_THROW_UNLESS(provided >= MPI_THREAD_SERIALIZED,
                        "MPI: this MPI library cannot be called from OpenMP threads one at a time");
    std::atexit([] {
      int finalized = 0;
      MPI_Finalized(&finalized);
      if (!finalized) MPI_Finalize();
    });
  }
  MPI_Comm_rank(MPI_COMM_WORLD, &mpi.rank);
  MPI_Comm_size(MPI_COMM_WORLD, &mpi.size);
  mpi.active = mpi.size > 1;
  return mpi;
}

// This rank's share of the runs to do: run i goes to rank i mod N.
std::vector<int> OwnShare(const Mpi& mpi, const std::vector<int>& todo) {
  std::vector<int> mine;
  for (std::size_t i = 0; i < todo.size(); ++i) {
    if (static_cast<int>(i % mpi.size) == mpi.rank) mine.push_back(todo[i]);
  }
  return mine;
}

// Rank 0's text to every rank.
std::string Broadcast(const Mpi& mpi, std::string text) {
  if (!mpi.active) return text;
  long n = static_cast<long>(text.size());
  MPI_Bcast(&n, 1, MPI_LONG, 0, MPI_COMM_WORLD);
  text.resize(n);
  if (n > 0) MPI_Bcast(text.data(), static_cast<int>(n), MPI_CHAR, 0, MPI_COMM_WORLD);
  return text;
}

void Send(const std::string& text, int tag) {
  MPI_Send(text.data(), static_cast<int>(text.size()), MPI_CHAR, 0, tag, MPI_COMM_WORLD);
}

// Receives one message on rank 0: its tag and text (blocking when `wait`, else nothing when
// none is pending: returns tag 0).
std::pair<int, std::string> Receive(bool wait) {
  MPI_Status status;
  int flag = 1;
  if (wait)
    MPI_Probe(MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &status);
  else
    MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &flag, &status);
  if (!flag) return {0, ""};
  int n = 0;
  MPI_Get_count(&status, MPI_CHAR, &n);
  std::string text(n, '\0');
  MPI_Recv(text.data(), n, MPI_CHAR, status.MPI_SOURCE, status.MPI_TAG, MPI_COMM_WORLD,
           MPI_STATUS_IGNORE);
  return {status.MPI_TAG, text};
}

}  // namespace

BenchReport RunBench(const BenchSpec& spec, const std::string& db_path,
                     const BenchOptions& options) {
  const auto t0 = Clock::now();
  BenchReport report;
  int progress_rank = 0;
  auto progress = [&](const std::string& line) {
    if (options.progress && progress_rank == 0) options.progress(line);
  };
  std::atomic<long> finished{0};
  auto tick = [&](long of, const char* phase) {
    const long done = finished.fetch_add(1) + 1;
    if (options.tick && progress_rank == 0 && omp_get_thread_num() == 0) options.tick(done, of, phase);
  };
  const Mpi mpi = StartMpi();
  report.rank = mpi.rank;
  progress_rank = mpi.rank;
  report.ranks = mpi.size;
  // The shared, immutable inputs: one robot, each patient once. Built before the database is
  // opened: a spec that fails here (an unknown arm, a patient that does not import) leaves no
  // database bound to it.
  auto robot = std::make_shared<const robot::RobotModel>(robot::LoadRobot(spec.robot));
  std::vector<PatientSetup> patients;
  for (const std::string& dir : spec.patients) {
    PatientSetup p;
    p.name = PatientName(dir);
    progress("importing " + p.name);
    p.model = patient::ImportCase(dir).model;
    ProblemOptions po;
    po.arms = spec.arms;
    po.samples_per_target = spec.samples_per_target;
    p.problem = std::make_unique<PortPlacementProblem>(p.model, robot, po);
    patients.push_back(std::move(p));
  }

  // Rank 0 owns the database; the others learn which runs are done from it.
  std::unique_ptr<BenchDatabase> db_owner;
  std::string open_error;
  if (mpi.rank == 0) {
    try {
      db_owner = std::make_unique<BenchDatabase>(db_path, spec.Canonical());
      db_owner->Enum("status", MotionStatusNames());
    } catch (const Error& e) {
      open_error = e.what();
    }
  }
  open_error = Broadcast(mpi, open_error);
  TROCAR_THROW_UNLESS(open_error.empty(), open_error);
  std::set<std::string> done;
  {
    std::string keys;
    if (db_owner) {
      for (const auto& k : db_owner->DoneKeys()) keys += k + "\n";
    }
    std::istringstream in(Broadcast(mpi, keys));
    for (std::string k; std::getline(in, k);) done.insert(k);
  }
  report.already_done = static_cast<long>(done.size());
  const int threads = options.threads >= 0 ? options.threads : spec.threads;
  report.threads = threads > 0 ? threads : omp_get_max_threads();

  // Experiments: port placement per patient; motions per patient and algorithm.
  std::vector<int> placement_experiment;
  for (const auto& p : patients) {
    ExperimentInfo info;
    info.name = spec.name + "_" + p.name + "_port_placement";
    info.timelimit = 0;
    info.runcount = static_cast<int>(spec.placement_seeds.size());
    info.seed = spec.placement_seeds.front();
    info.setup = "port placement for " + p.name + " with " + robot->name() + ": " +
                 std::to_string(spec.evaluations) + " evaluations, " +
                 std::to_string(spec.polish_evaluations) + " polish evaluations";
    placement_experiment.push_back(db_owner ? db_owner->Experiment(info) : 0);
  }
  std::vector<int> algorithm_config;
  for (const auto& a : spec.algorithms) {
    std::ostringstream settings;
    settings << "evaluations INTEGER = " << spec.evaluations << "\n;polish_evaluations INTEGER = "
             << spec.polish_evaluations << "\n;top_k INTEGER = " << spec.top_k << "\n;";
    algorithm_config.push_back(
        db_owner ? db_owner->PlannerConfig("portplacement_" + a.name(), settings.str()) : 0);
  }

  // Phase 1: placement runs.
  std::vector<PlacementRun> placement_runs;
  for (int p = 0; p < static_cast<int>(patients.size()); ++p) {
    for (int a = 0; a < static_cast<int>(spec.algorithms.size()); ++a) {
      for (unsigned seed : spec.placement_seeds) {
        PlacementRun r{p, a, seed,
                       "placement/" + patients[p].name + "/" + spec.algorithms[a].name() + "/" +
                           std::to_string(seed)};
        placement_runs.push_back(r);
      }
    }
  }
  std::vector<int> todo;
  for (int i = 0; i < static_cast<int>(placement_runs.size()); ++i) {
    if (!done.count(placement_runs[i].key)) todo.push_back(i);
  }
  report.runs += static_cast<long>(placement_runs.size());
  long budget = options.max_new_runs;
  auto take = [&budget]() {
    if (budget == 0) return false;
    if (budget > 0) --budget;
    return true;
  };
  std::string error;
  // A finished run: into the database (rank 0), or to rank 0 (other ranks). Called inside the
  // critical section. Rank 0 also takes in what the other ranks have sent meanwhile.
  std::function<void(const std::string&)> insert_message;  // set per phase, rank 0
  int workers_done = 0;  // of this phase (a worker's end may arrive while rank 0 still works)
  auto drain = [&](bool until_done) {
    while (true) {
      if (until_done && workers_done == mpi.size - 1) break;
      const auto [tag, text] = Receive(until_done);
      if (tag == 0) break;
      if (tag == Mpi::kDone) ++workers_done;
      if (tag == Mpi::kError && error.empty()) error = text;
      if (tag == Mpi::kResult) insert_message(text);
    }
  };
  auto deliver = [&](int kind, int index, const RunValues& v, const std::string& payload) {
    nlohmann::json values = nlohmann::json::array();
    for (const auto& x : v)
      values.push_back(x && std::isfinite(*x) ? nlohmann::json(*x) : nlohmann::json());
    const std::string text =
        nlohmann::json{{"k", kind}, {"i", index}, {"p", payload}, {"v", values}}.dump();
    if (mpi.rank == 0) {
      insert_message(text);
      if (mpi.active) drain(false);
    } else {
      Send(text, Mpi::kResult);
    }
  };
  auto decode = [](const std::string& text, RunValues* v, std::string* payload) {
    const nlohmann::json m = nlohmann::json::parse(text);
    v->clear();
    for (const auto& x : m.at("v")) {
      if (x.is_null())
        v->push_back(std::nullopt);
      else
        v->push_back(x.get<double>());
    }
    *payload = m.at("p").get<std::string>();
    return m.at("i").get<int>();
  };
  // End of a phase: workers say so; rank 0 waits for all of them, then tells every rank whether
  // the phase failed.
  auto end_phase = [&]() {
    if (!mpi.active) return;
    if (mpi.rank != 0) {
      if (!error.empty()) Send(error, Mpi::kError);
      Send("", Mpi::kDone);
    } else {
      drain(true);
      workers_done = 0;
    }
    error = Broadcast(mpi, error);
  };
  insert_message = [&](const std::string& text) {
    RunValues v;
    std::string payload;
    const int index = decode(text, &v, &payload);
    const PlacementRun& run = placement_runs.at(index);
    db_owner->AddRun(run.key, placement_experiment[run.patient], algorithm_config[run.algorithm],
                     PlacementProperties(), v, payload);
    ++report.added;
  };
  todo = OwnShare(mpi, todo);
  progress("placement runs: " + std::to_string(todo.size()) + " to do of " +
           std::to_string(placement_runs.size()));
#pragma omp parallel for schedule(dynamic, 1) num_threads(report.threads)
  for (int t = 0; t < static_cast<int>(todo.size()); ++t) {
    bool go = false;
#pragma omp critical(trocar_bench_db)
    go = error.empty() && take();
    if (!go) continue;
    const PlacementRun& run = placement_runs[todo[t]];
    try {
      PortPlacementOptions o;
      o.algorithm = spec.algorithms[run.algorithm].global;
      o.local = spec.algorithms[run.algorithm].local;
      o.evaluations = spec.evaluations;
      o.polish_evaluations = spec.polish_evaluations;
      o.top_k = spec.top_k;
      o.seed = run.seed;
      o.threads = 1;
      o.robustness_shift = 0.0;
      o.time_limit = 24 * 3600;  // the budget, not the clock, ends a run
      const auto r0 = Clock::now();
      const PortPlacementResult result = OptimizePorts(*patients[run.patient].problem, o);
      const double seconds = std::chrono::duration<double>(Clock::now() - r0).count();
      RunValues v(PlacementProperties().size());
      v[0] = seconds;
      v[1] = result.verdict.suitable ? 1.0 : 0.0;
      v[5] = result.evaluations;
      v[6] = run.seed;
      nlohmann::json payload = nlohmann::json::object();
      if (!result.plans.empty()) {
        const RankedPlan& best = result.plans.front();
        const Evaluation& ev = best.evaluation;
        v[2] = ev.score;
        v[3] = best.rank_score;
        v[7] = ev.status == PlacementStatus::kPlaced ? 1.0 : 0.0;
        v[8] = ev.collisions;
        const char* terms[] = {"coverage", nullptr, nullptr, nullptr, nullptr,
                               nullptr, nullptr, nullptr, nullptr, "dexterity", "approach",
                               "triangulation", "endoscope", "spacing", "clearance_arm_arm",
                               "clearance_arm_patient", "clearance_instrument_rib"};
        for (int i = 0; i < static_cast<int>(v.size()); ++i) {
          if (i == 4 || i >= 9) {
            const ScoreTerm* term = ev.Find(terms[i == 4 ? 0 : i]);
            if (term) v[i] = i == 4 ? term->value : term->score;
          }
        }
        // The placement exactly (not its decision vector, which a round trip through
        // Encode and Decode changes in the last bits: enough for the setup-joint solver to land
        // elsewhere).
        nlohmann::json sites = nlohmann::json::array();
        for (const PortSite& site : best.placement.sites)
          sites.push_back({{"candidate", site.candidate}, {"s", site.s}});
        payload["sites"] = sites;
        payload["cart"] = {best.placement.cart_x, best.placement.cart_y, best.placement.cart_yaw};
      }
#pragma omp critical(trocar_bench_db)
      deliver(0, todo[t], v, payload.dump());
      tick(static_cast<long>(todo.size()), "placement runs");
    } catch (const std::exception& e) {
#pragma omp critical(trocar_bench_db)
      if (error.empty()) error = run.key + ": " + e.what();
    }
  }
  end_phase();
  TROCAR_THROW_UNLESS(error.empty(), error);

  // Phase 2: motion runs on each (patient, algorithm)'s top plan of the first placement seed.
  std::vector<MotionExperiment> experiments;
  std::vector<MotionRun> motion_runs;
  const std::string first_seed = std::to_string(spec.placement_seeds.front());
  for (int p = 0; p < static_cast<int>(patients.size()); ++p) {
    const PortPlacementProblem& problem = *patients[p].problem;
    for (int a = 0; a < static_cast<int>(spec.algorithms.size()); ++a) {
      MotionExperiment e;
      e.patient = p;
      e.algorithm = a;
      for (int arm = 0; arm < static_cast<int>(problem.arms().size()); ++arm) {
        if (problem.arms()[arm].role == ArmRole::kInstrument) e.instruments.push_back(arm);
      }
      ExperimentInfo info;
      info.name = spec.name + "_" + patients[p].name + "_" + spec.algorithms[a].name() + "_motions";
      info.timelimit = spec.time_limit;
      info.runcount = static_cast<int>(spec.motion_seeds.size() * e.instruments.size() *
                                       problem.samples().size());
      info.seed = spec.motion_seeds.front();
      info.setup = "motions of each instrument arm to each of " +
                   std::to_string(problem.samples().size()) + " target samples of " +
                   patients[p].name + ", from the top plan of " + spec.algorithms[a].name() +
                   " (seed " + first_seed + ")";
      e.experiment_id = db_owner ? db_owner->Experiment(info) : 0;
      // The plan, from the placement run's recorded decision vector (runs of an interrupted
      // bench included); its start pose by a detailed evaluation.
      const std::string payload = Broadcast(
          mpi, db_owner ? db_owner->Payload("placement/" + patients[p].name + "/" +
                                            spec.algorithms[a].name() + "/" + first_seed)
                        : std::string());
      nlohmann::json j = payload.empty()
                            ? nlohmann::json()
                            : ParseJsonText(payload, db_path + " (a stored run's placement; the "
                                                     "database is damaged)");
      if (j.is_object() && j.contains("sites")) {
        Placement placement;
        for (const auto& site : j["sites"])
          placement.sites.push_back(
              problem.Site(site.at("candidate").get<int>(), site.at("s").get<double>()));
        placement.cart_x = j["cart"].at(0).get<double>();
        placement.cart_y = j["cart"].at(1).get<double>();
        placement.cart_yaw = j["cart"].at(2).get<double>();
        Workspace ws(problem);
        const Evaluation ev = EvaluateFinalPlan(problem, placement, &ws);
        e.placed = ev.status == PlacementStatus::kPlaced;
        e.why_not = ev.status == PlacementStatus::kInCollision
                        ? "the plan's nominal pose is in collision"
                        : "the plan's arms are not placed at their ports";
        if (e.placed) e.problem = std::make_unique<MotionProblem>(problem, placement, ev);
      } else {
        e.why_not = "no plan";
      }
      const int index = static_cast<int>(experiments.size());
      for (int pl = 0; pl < static_cast<int>(spec.planners.size()); ++pl) {
        for (unsigned seed : spec.motion_seeds) {
          for (int arm : e.instruments) {
            for (int s = 0; s < static_cast<int>(problem.samples().size()); ++s) {
              motion_runs.push_back(
                  {index, pl, seed, arm, s,
                   "motion/" + patients[p].name + "/" + spec.algorithms[a].name() + "/" +
                       spec.planners[pl] + "/" + std::to_string(seed) + "/" +
                       problem.arms()[arm].name + "/" + std::to_string(s)});
            }
          }
        }
      }
      experiments.push_back(std::move(e));
    }
  }
  std::vector<int> planner_config;
  for (const auto& pl : spec.planners)
    planner_config.push_back(db_owner ? db_owner->PlannerConfig("geometric_" + OmplPlannerName(pl),
                                                                PlannerSettings(pl, spec))
                                      : 0);
  report.runs += static_cast<long>(motion_runs.size());
  todo.clear();
  for (int i = 0; i < static_cast<int>(motion_runs.size()); ++i) {
    if (!done.count(motion_runs[i].key)) todo.push_back(i);
  }
  todo = OwnShare(mpi, todo);
  insert_message = [&](const std::string& text) {
    RunValues v;
    std::string payload;
    const int index = decode(text, &v, &payload);
    const MotionRun& run = motion_runs.at(index);
    db_owner->AddRun(run.key, experiments[run.experiment].experiment_id,
                     planner_config[run.planner], MotionProperties(), v, payload);
    ++report.added;
  };
  finished.store(0);
  progress("motion runs: " + std::to_string(todo.size()) + " to do of " +
           std::to_string(motion_runs.size()));
#pragma omp parallel num_threads(report.threads)
  {
    // This thread's OMPL and collision scratch, one per experiment it meets.
    std::map<int, std::unique_ptr<MotionContext>> contexts;
#pragma omp for schedule(dynamic, 1)
    for (int t = 0; t < static_cast<int>(todo.size()); ++t) {
      bool go = false;
#pragma omp critical(trocar_bench_db)
      go = error.empty() && take();
      if (!go) continue;
      const MotionRun& run = motion_runs[todo[t]];
      const MotionExperiment& e = experiments[run.experiment];
      try {
        TargetMotion m;
        if (!e.placed) {
          m.status = MotionStatus::kInvalidStart;
          m.reason = e.why_not;
        } else {
          auto& context = contexts[run.experiment];
          if (!context) context = std::make_unique<MotionContext>(*e.problem);
          MotionOptions mo;
          mo.planner = spec.planners[run.planner];
          mo.time_limit = spec.time_limit;
          mo.seed = run.seed;
          m = context->Plan(run.arm, run.sample, mo);
        }
        RunValues v(MotionProperties().size());
        const bool has_path = !m.path.empty();
        v[0] = m.planning_time;
        v[1] = m.solved ? 1.0 : 0.0;
        v[2] = static_cast<double>(static_cast<int>(m.status));
        v[3] = m.status == MotionStatus::kApproximateSolution ? 1.0 : 0.0;
        if (has_path) {
          v[4] = m.correct ? 1.0 : 0.0;
          v[5] = m.raw_path_length;
          v[6] = m.min_clearance;
          v[7] = m.segments;
          v[8] = m.simplification_time;
          v[9] = m.path_length;
          v[10] = m.min_clearance;
          v[11] = m.segments;
          v[12] = m.correct ? 1.0 : 0.0;
        }
        v[13] = static_cast<double>(m.graph_states);
        v[14] = static_cast<double>(m.graph_motions);
        v[15] = run.seed;
        v[16] = run.arm;
        v[17] = run.sample;
        if (has_path) {
          v[18] = m.tip_path_length;
          v[19] = m.rechecked_states;
        }
        nlohmann::json payload = {{"outcome", m.outcome}, {"reason", m.reason}};
#pragma omp critical(trocar_bench_db)
        deliver(1, todo[t], v, payload.dump());
        tick(static_cast<long>(todo.size()), "motion runs");
      } catch (const std::exception& ex) {
#pragma omp critical(trocar_bench_db)
        if (error.empty()) error = run.key + ": " + ex.what();
      }
    }
  }
  end_phase();
  TROCAR_THROW_UNLESS(error.empty(), error);
  if (db_owner) {
    db_owner->UpdateTotalTimes();
    report.in_database = db_owner->RunCount();
    report.logs = db_owner->WriteLogs(db_path);
  }
  report.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return report;
}

}  // namespace trocar::planners
