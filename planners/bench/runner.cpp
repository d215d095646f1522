#include "bench/runner.hpp"

// The C API only (OpenMPI otherwise pulls in its deprecated C++ bindings).
#define OMPI_SKIP_MPICXX 1
#define MPICH_SKIP_MPICXX 1
#include <mpi.h>
#include <omp.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <utility>

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

// The runs' results on their way to the database. Rank 0 inserts its own at once and takes in
// what the other ranks have sent meanwhile; the other ranks send each result to rank 0 as one
// message (JSON text). Called inside the critical section `trocar_bench_db`.
class ResultChannel {
 public:
  explicit ResultChannel(const Mpi& mpi) : mpi_(mpi) {}

  /// The phase's first failure (a run's key and why), shared by every rank at the phase's end.
  std::string error;
  /// Rank 0: puts a finished run of this phase into the database.
  std::function<void(int index, const RunValues& values, const std::string& payload)> insert;

  void Deliver(int kind, int index, const RunValues& v, const std::string& payload) {
    nlohmann::json values = nlohmann::json::array();
    for (const auto& x : v)
      values.push_back(x && std::isfinite(*x) ? nlohmann::json(*x) : nlohmann::json());
    const std::string text =
        nlohmann::json{{"k", kind}, {"i", index}, {"p", payload}, {"v", values}}.dump();
    if (mpi_.rank == 0) {
      Insert(text);
      if (mpi_.active) Drain(false);
    } else {
      Send(text, Mpi::kResult);
    }
  }

  /// End of a phase: workers say so; rank 0 waits for all of them, then tells every rank whether
  /// the phase failed.
  void EndPhase() {
    if (!mpi_.active) return;
    if (mpi_.rank != 0) {
      if (!error.empty()) Send(error, Mpi::kError);
      Send("", Mpi::kDone);
    } else {
      Drain(true);
      workers_done_ = 0;
    }
    error = Broadcast(mpi_, error);
  }

 private:
  void Insert(const std::string& text) {
    const nlohmann::json m = nlohmann::json::parse(text);
    RunValues v;
    for (const auto& x : m.at("v")) {
      if (x.is_null())
        v.push_back(std::nullopt);
      else
        v.push_back(x.get<double>());
    }
    insert(m.at("i").get<int>(), v, m.at("p").get<std::string>());
  }

  // Rank 0 takes in the other ranks' messages: those pending, or (`until_done`) until every
  // worker has ended the phase (a worker's end may arrive while rank 0 still works).
  void Drain(bool until_done) {
    while (true) {
      if (until_done && workers_done_ == mpi_.size - 1) break;
      const auto [tag, text] = Receive(until_done);
      if (tag == 0) break;
      if (tag == Mpi::kDone) ++workers_done_;
      if (tag == Mpi::kError && error.empty()) error = text;
      if (tag == Mpi::kResult) Insert(text);
    }
  }

  const Mpi& mpi_;
  int workers_done_ = 0;
};

// One placement run: its values (PlacementProperties' order) and its payload, the best plan's
// placement exactly (not its decision vector, which a round trip through Encode and Decode
// changes in the last bits: enough for the setup-joint solver to land elsewhere).
std::pair<RunValues, std::string> RunPlacement(const PortPlacementProblem& problem,
                                               const BenchSpec& spec, const PlacementRun& run) {
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
  const PortPlacementResult result = OptimizePorts(problem, o);
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
    const char* terms[] = {"coverage",
                           nullptr,
                           nullptr,
                           nullptr,
                           nullptr,
                           nullptr,
                           nullptr,
                           nullptr,
                           nullptr,
                           "dexterity",
                           "approach",
                           "triangulation",
                           "endoscope",
                           "spacing",
                           "clearance_arm_arm",
                           "clearance_arm_patient",
                           "clearance_instrument_rib"};
    for (int i = 0; i < static_cast<int>(v.size()); ++i) {
      if (i == 4 || i >= 9) {
        const ScoreTerm* term = ev.Find(terms[i == 4 ? 0 : i]);
        if (term) v[i] = i == 4 ? term->value : term->score;
      }
    }
    nlohmann::json sites = nlohmann::json::array();
    for (const PortSite& site : best.placement.sites)
      sites.push_back({{"candidate", site.candidate}, {"s", site.s}});
    payload["sites"] = sites;
    payload["cart"] = {best.placement.cart_x, best.placement.cart_y, best.placement.cart_yaw,
                       best.placement.table_raise};
  }
  return {v, payload.dump()};
}

// One motion run's values (MotionProperties' order).
RunValues MotionValues(const TargetMotion& m, const MotionRun& run) {
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
  return v;
}

// A bench as stages: its inputs (LoadInputs), the database (OpenDatabase), the placement runs
// (PlacementPhase), the motion runs on each (patient, algorithm)'s top plan (MotionExperiments,
// MotionPhase), then the database's totals and logs (Finish).
class Bench {
 public:
  Bench(const BenchSpec& spec, const std::string& db_path, const BenchOptions& options)
      : spec_(spec), db_path_(db_path), options_(options), mpi_(StartMpi()), channel_(mpi_) {
    report_.rank = mpi_.rank;
    report_.ranks = mpi_.size;
    budget_ = options.max_new_runs;
  }

  BenchReport Run() {
    const auto t0 = Clock::now();
    LoadInputs();
    OpenDatabase();
    PlacementPhase();
    MotionPhase();
    if (db_) {
      db_->UpdateTotalTimes();
      report_.in_database = db_->RunCount();
      report_.logs = db_->WriteLogs(db_path_);
    }
    report_.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    return report_;
  }

 private:
  void Progress(const std::string& line) const {
    if (options_.progress && mpi_.rank == 0) options_.progress(line);
  }
  void Tick(long of, const char* phase) {
    const long done = finished_.fetch_add(1) + 1;
    if (options_.tick && mpi_.rank == 0 && omp_get_thread_num() == 0)
      options_.tick(done, of, phase);
  }
  // Whether another new run may start (BenchOptions::max_new_runs); inside the critical section.
  bool Take() {
    if (budget_ == 0) return false;
    if (budget_ > 0) --budget_;
    return true;
  }
  // Of `all` (keys), the indices not yet in the database that are this rank's.
  template <typename RunT>
  std::vector<int> ToDo(const std::vector<RunT>& all) const {
    std::vector<int> todo;
    for (int i = 0; i < static_cast<int>(all.size()); ++i) {
      if (!done_.count(all[i].key)) todo.push_back(i);
    }
    return OwnShare(mpi_, todo);
  }

  // The shared, immutable inputs: one robot, each patient once. Built before the database is
  // opened: a spec that fails here (an unknown arm, a patient that does not import) leaves no
  // database bound to it.
  void LoadInputs() {
    robot_ = std::make_shared<const robot::RobotModel>(robot::LoadRobot(spec_.robot));
    for (const std::string& dir : spec_.patients) {
      PatientSetup p;
      p.name = PatientName(dir);
      Progress("importing " + p.name);
      p.model = patient::ImportCase(dir).model;
      ProblemOptions po;
      po.arms = spec_.arms;
      po.samples_per_target = spec_.samples_per_target;
      p.problem = std::make_unique<PortPlacementProblem>(p.model, robot_, po);
      patients_.push_back(std::move(p));
    }
  }

  // Rank 0 owns the database; the others learn which runs are done from it.
  void OpenDatabase() {
    std::string open_error;
    if (mpi_.rank == 0) {
      try {
        db_ = std::make_unique<BenchDatabase>(db_path_, spec_.Canonical());
        db_->Enum("status", MotionStatusNames());
      } catch (const Error& e) {
        open_error = e.what();
      }
    }
    open_error = Broadcast(mpi_, open_error);
    TROCAR_THROW_UNLESS(open_error.empty(), open_error);
    std::string keys;
    if (db_) {
      for (const auto& k : db_->DoneKeys()) keys += k + "\n";
    }
    std::istringstream in(Broadcast(mpi_, keys));
    for (std::string k; std::getline(in, k);) done_.insert(k);
    report_.already_done = static_cast<long>(done_.size());
    const int threads = options_.threads >= 0 ? options_.threads : spec_.threads;
    report_.threads = threads > 0 ? threads : omp_get_max_threads();
  }

  // Phase 1: placement runs, an experiment per patient, a planner configuration per algorithm.
  void PlacementPhase() {
    std::vector<int> experiment;
    for (const auto& p : patients_) {
      ExperimentInfo info;
      info.name = spec_.name + "_" + p.name + "_port_placement";
      info.timelimit = 0;
      info.runcount = static_cast<int>(spec_.placement_seeds.size());
      info.seed = spec_.placement_seeds.front();
      info.setup = "port placement for " + p.name + " with " + robot_->name() + ": " +
                   std::to_string(spec_.evaluations) + " evaluations, " +
                   std::to_string(spec_.polish_evaluations) + " polish evaluations";
      experiment.push_back(db_ ? db_->Experiment(info) : 0);
    }
    std::vector<int> config;
    for (const auto& a : spec_.algorithms) {
      std::ostringstream settings;
      settings << "evaluations INTEGER = " << spec_.evaluations
               << "\n;polish_evaluations INTEGER = " << spec_.polish_evaluations
               << "\n;top_k INTEGER = " << spec_.top_k << "\n;";
      config.push_back(db_ ? db_->PlannerConfig("portplacement_" + a.name(), settings.str()) : 0);
    }
    std::vector<PlacementRun> runs;
    for (int p = 0; p < static_cast<int>(patients_.size()); ++p) {
      for (int a = 0; a < static_cast<int>(spec_.algorithms.size()); ++a) {
        for (unsigned seed : spec_.placement_seeds) {
          runs.push_back({p, a, seed,
                          "placement/" + patients_[p].name + "/" + spec_.algorithms[a].name() +
                              "/" + std::to_string(seed)});
        }
      }
    }
    report_.runs += static_cast<long>(runs.size());
    const std::vector<int> todo = ToDo(runs);
    channel_.insert = [&](int index, const RunValues& v, const std::string& payload) {
      const PlacementRun& run = runs.at(index);
      db_->AddRun(run.key, experiment[run.patient], config[run.algorithm], PlacementProperties(), v,
                  payload);
      ++report_.added;
    };
    Progress("placement runs: " + std::to_string(todo.size()) + " to do of " +
             std::to_string(runs.size()));
#pragma omp parallel for schedule(dynamic, 1) num_threads(report_.threads)
    for (int t = 0; t < static_cast<int>(todo.size()); ++t) {
      bool go = false;
#pragma omp critical(trocar_bench_db)
      go = channel_.error.empty() && Take();
      if (!go) continue;
      const PlacementRun& run = runs[todo[t]];
      try {
        const std::pair<RunValues, std::string> result =
            RunPlacement(*patients_[run.patient].problem, spec_, run);
#pragma omp critical(trocar_bench_db)
        channel_.Deliver(0, todo[t], result.first, result.second);
        Tick(static_cast<long>(todo.size()), "placement runs");
      } catch (const std::exception& e) {
#pragma omp critical(trocar_bench_db)
        if (channel_.error.empty()) channel_.error = run.key + ": " + e.what();
      }
    }
    channel_.EndPhase();
    channel_.insert = nullptr;  // it refers to this phase's runs
    TROCAR_THROW_UNLESS(channel_.error.empty(), channel_.error);
  }

  // The motion experiment of patient `p` and algorithm `a`: the top plan of the first placement
  // seed, from the placement run's recorded placement (runs of an interrupted bench included), its
  // start pose by a detailed evaluation; its runs appended to `runs`.
  MotionExperiment MotionExperimentOf(int p, int a, int index, std::vector<MotionRun>* runs) {
    const PortPlacementProblem& problem = *patients_[p].problem;
    const std::string first_seed = std::to_string(spec_.placement_seeds.front());
    MotionExperiment e;
    e.patient = p;
    e.algorithm = a;
    for (int arm = 0; arm < static_cast<int>(problem.arms().size()); ++arm) {
      if (problem.arms()[arm].role == ArmRole::kInstrument) e.instruments.push_back(arm);
    }
    ExperimentInfo info;
    info.name =
        spec_.name + "_" + patients_[p].name + "_" + spec_.algorithms[a].name() + "_motions";
    info.timelimit = spec_.time_limit;
    info.runcount = static_cast<int>(spec_.motion_seeds.size() * e.instruments.size() *
                                     problem.samples().size());
    info.seed = spec_.motion_seeds.front();
    info.setup = "motions of each instrument arm to each of " +
                 std::to_string(problem.samples().size()) + " target samples of " +
                 patients_[p].name + ", from the top plan of " + spec_.algorithms[a].name() +
                 " (seed " + first_seed + ")";
    e.experiment_id = db_ ? db_->Experiment(info) : 0;
    const std::string payload =
        Broadcast(mpi_, db_ ? db_->Payload("placement/" + patients_[p].name + "/" +
                                           spec_.algorithms[a].name() + "/" + first_seed)
                            : std::string());
    nlohmann::json j = payload.empty()
                           ? nlohmann::json()
                           : ParseJsonText(payload, db_path_ +
                                                        " (a stored run's placement; the "
                                                        "database is damaged)");
    if (j.is_object() && j.contains("sites")) {
      Placement placement;
      for (const auto& site : j["sites"])
        placement.sites.push_back(
            problem.Site(site.at("candidate").get<int>(), site.at("s").get<double>()));
      placement.cart_x = j["cart"].at(0).get<double>();
      placement.cart_y = j["cart"].at(1).get<double>();
      placement.cart_yaw = j["cart"].at(2).get<double>();
      // The table's raise: a fourth value since stop 64 (databases before it: the case's table).
      if (j["cart"].size() > 3) placement.table_raise = j["cart"].at(3).get<double>();
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
    for (int pl = 0; pl < static_cast<int>(spec_.planners.size()); ++pl) {
      for (unsigned seed : spec_.motion_seeds) {
        for (int arm : e.instruments) {
          for (int s = 0; s < static_cast<int>(problem.samples().size()); ++s) {
            runs->push_back({index, pl, seed, arm, s,
                             "motion/" + patients_[p].name + "/" + spec_.algorithms[a].name() +
                                 "/" + spec_.planners[pl] + "/" + std::to_string(seed) + "/" +
                                 problem.arms()[arm].name + "/" + std::to_string(s)});
          }
        }
      }
    }
    return e;
  }

  // Phase 2: motion runs on each (patient, algorithm)'s top plan of the first placement seed.
  void MotionPhase() {
    std::vector<MotionExperiment> experiments;
    std::vector<MotionRun> runs;
    for (int p = 0; p < static_cast<int>(patients_.size()); ++p) {
      for (int a = 0; a < static_cast<int>(spec_.algorithms.size()); ++a)
        experiments.push_back(
            MotionExperimentOf(p, a, static_cast<int>(experiments.size()), &runs));
    }
    std::vector<int> config;
    for (const auto& pl : spec_.planners)
      config.push_back(
          db_ ? db_->PlannerConfig("geometric_" + OmplPlannerName(pl), PlannerSettings(pl, spec_))
              : 0);
    report_.runs += static_cast<long>(runs.size());
    const std::vector<int> todo = ToDo(runs);
    channel_.insert = [&](int index, const RunValues& v, const std::string& payload) {
      const MotionRun& run = runs.at(index);
      db_->AddRun(run.key, experiments[run.experiment].experiment_id, config[run.planner],
                  MotionProperties(), v, payload);
      ++report_.added;
    };
    finished_.store(0);
    Progress("motion runs: " + std::to_string(todo.size()) + " to do of " +
             std::to_string(runs.size()));
#pragma omp parallel num_threads(report_.threads)
    {
      // This thread's OMPL and collision scratch, one per experiment it meets.
      std::map<int, std::unique_ptr<MotionContext>> contexts;
#pragma omp for schedule(dynamic, 1)
      for (int t = 0; t < static_cast<int>(todo.size()); ++t) {
        bool go = false;
#pragma omp critical(trocar_bench_db)
        go = channel_.error.empty() && Take();
        if (!go) continue;
        const MotionRun& run = runs[todo[t]];
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
            mo.planner = spec_.planners[run.planner];
            mo.time_limit = spec_.time_limit;
            mo.seed = run.seed;
            m = context->Plan(run.arm, run.sample, mo);
          }
          const RunValues v = MotionValues(m, run);
          const nlohmann::json payload = {{"outcome", m.outcome}, {"reason", m.reason}};
#pragma omp critical(trocar_bench_db)
          channel_.Deliver(1, todo[t], v, payload.dump());
          Tick(static_cast<long>(todo.size()), "motion runs");
        } catch (const std::exception& ex) {
#pragma omp critical(trocar_bench_db)
          if (channel_.error.empty()) channel_.error = run.key + ": " + ex.what();
        }
      }
    }
    channel_.EndPhase();
    channel_.insert = nullptr;  // it refers to this phase's runs
    TROCAR_THROW_UNLESS(channel_.error.empty(), channel_.error);
  }

  const BenchSpec& spec_;
  const std::string& db_path_;
  const BenchOptions& options_;
  const Mpi mpi_;
  ResultChannel channel_;
  BenchReport report_;
  std::shared_ptr<const robot::RobotModel> robot_;
  std::vector<PatientSetup> patients_;
  std::unique_ptr<BenchDatabase> db_;  // rank 0
  std::set<std::string> done_;         // run keys already in the database
  long budget_ = -1;                   // new runs that may still start (< 0: no limit)
  std::atomic<long> finished_{0};      // runs this process finished in the phase
};

}  // namespace

BenchReport RunBench(const BenchSpec& spec, const std::string& db_path,
                     const BenchOptions& options) {
  return Bench(spec, db_path, options).Run();
}

}  // namespace trocar::planners
