#include "bench/database.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <cerrno>
#include <cstring>
#include <sqlite3.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar::planners {

namespace {

// The schema of OMPL 1.5.2's ompl_benchmark_statistics.py (readBenchmarkLog), table by table.
constexpr const char* kOmplSchema = R"(
CREATE TABLE IF NOT EXISTS experiments
  (id INTEGER PRIMARY KEY AUTOINCREMENT, name VARCHAR(512),
  totaltime REAL, timelimit REAL, memorylimit REAL, runcount INTEGER,
  version VARCHAR(128), hostname VARCHAR(1024), cpuinfo TEXT,
  date DATETIME, seed VARCHAR(24), setup TEXT);
CREATE TABLE IF NOT EXISTS plannerConfigs
  (id INTEGER PRIMARY KEY AUTOINCREMENT,
  name VARCHAR(512) NOT NULL, settings TEXT);
CREATE TABLE IF NOT EXISTS enums
  (name VARCHAR(512), value INTEGER, description TEXT,
  PRIMARY KEY (name, value));
CREATE TABLE IF NOT EXISTS runs
  (id INTEGER PRIMARY KEY AUTOINCREMENT, experimentid INTEGER, plannerid INTEGER,
  FOREIGN KEY (experimentid) REFERENCES experiments(id) ON DELETE CASCADE,
  FOREIGN KEY (plannerid) REFERENCES plannerConfigs(id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS progress
  (runid INTEGER, time REAL, PRIMARY KEY (runid, time),
  FOREIGN KEY (runid) REFERENCES runs(id) ON DELETE CASCADE);
)";

// trocar's own tables: the spec the database belongs to, the done runs, the property types.
constexpr const char* kTrocarSchema = R"(
CREATE TABLE IF NOT EXISTS trocar_bench (key TEXT PRIMARY KEY, value TEXT);
CREATE TABLE IF NOT EXISTS trocar_runs
  (key TEXT PRIMARY KEY, runid INTEGER, payload TEXT,
  FOREIGN KEY (runid) REFERENCES runs(id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS trocar_properties (name TEXT PRIMARY KEY, type TEXT, position INTEGER);
)";

class Statement {
 public:
  Statement(sqlite3* db, const std::string& sql, const std::string& path) : path_(path) {
    if (sqlite3_prepare_v2(db, sql.c_str(), -1, &stmt_, nullptr) != SQLITE_OK) {
      const std::string message = sqlite3_errmsg(db);
      TROCAR_THROW(path << ": " << message << " (in: " << sql.substr(0, 80) << ")");
    }
  }
  ~Statement() { sqlite3_finalize(stmt_); }
  Statement& Bind(int i, const std::string& s) {
    sqlite3_bind_text(stmt_, i, s.c_str(), -1, SQLITE_TRANSIENT);
    return *this;
  }
  Statement& Bind(int i, double v) {
    sqlite3_bind_double(stmt_, i, v);
    return *this;
  }
  Statement& BindInt(int i, long v) {
    sqlite3_bind_int64(stmt_, i, v);
    return *this;
  }
  Statement& BindNull(int i) {
    sqlite3_bind_null(stmt_, i);
    return *this;
  }
  /// true while there is a row.
  bool Step() {
    const int rc = sqlite3_step(stmt_);
    if (rc == SQLITE_ROW) return true;
    TROCAR_THROW_UNLESS(rc == SQLITE_DONE,
                        path_ << ": " << sqlite3_errmsg(sqlite3_db_handle(stmt_)));
    return false;
  }
  std::string Text(int c) const {
    const unsigned char* t = sqlite3_column_text(stmt_, c);
    return t ? reinterpret_cast<const char*>(t) : "";
  }
  double Real(int c) const { return sqlite3_column_double(stmt_, c); }
  long Int(int c) const { return sqlite3_column_int64(stmt_, c); }
  bool Null(int c) const { return sqlite3_column_type(stmt_, c) == SQLITE_NULL; }
  int Columns() const { return sqlite3_column_count(stmt_); }
  std::string ColumnNameAt(int c) const { return sqlite3_column_name(stmt_, c); }

 private:
  sqlite3_stmt* stmt_ = nullptr;
  std::string path_;
};

std::set<std::string> Tables(sqlite3* db, const std::string& path) {
  std::set<std::string> tables;
  Statement s(db, "SELECT name FROM sqlite_master WHERE type='table'", path);
  while (s.Step()) tables.insert(s.Text(0));
  return tables;
}

bool HasOmplTables(const std::set<std::string>& t) {
  return t.count("experiments") && t.count("plannerConfigs") && t.count("enums") &&
         t.count("runs") && t.count("progress");
}

std::string Hostname() {
  char name[256] = {0};
  if (gethostname(name, sizeof(name) - 1) != 0) return "unknown";
  std::string h = name;
  for (char& c : h) {
    if (c == ' ') c = '_';
  }
  return h.empty() ? "unknown" : h;
}

std::string Now() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[64];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%S", &tm);
  return buf;
}

// OMPL's log writes numbers as C++ streams do; nan and inf are read back as NULL.
std::string LogNumber(double v, const std::string& type) {
  std::ostringstream s;
  if (type == "BOOLEAN" || type == "ENUM" || type == "INTEGER") {
    s << static_cast<long>(std::llround(v));
  } else {
    s.precision(12);
    s << v;
  }
  return s.str();
}

}  // namespace

std::string ColumnName(const std::string& property) {
  std::string c;
  std::istringstream words(property);
  for (std::string w; words >> w;) c += (c.empty() ? "" : "_") + w;
  return c;
}

void BenchDatabase::CheckIsOmplDatabase(const std::string& path) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": no such database");
  sqlite3* db = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr);
  std::set<std::string> tables;
  std::string error;
  if (rc == SQLITE_OK) {
    try {
      tables = Tables(db, path);
    } catch (const Error& e) {
      error = e.what();
    }
  } else {
    error = sqlite3_errmsg(db);
  }
  sqlite3_close(db);
  TROCAR_THROW_UNLESS(error.empty(), path << ": not an SQLite database (" << error << ")");
  TROCAR_THROW_UNLESS(HasOmplTables(tables),
                      path << ": not an OMPL benchmark database (no experiments, plannerConfigs, "
                              "enums, runs and progress tables)");
}

BenchDatabase::Lock::~Lock() {
  if (fd >= 0) ::close(fd);  // closing releases the lock
}

BenchDatabase::BenchDatabase(const std::string& path, const std::string& spec) : path_(path) {
  // One writer: two benches on one database would race to create its schema and interleave
  // their runs. The lock is taken before the file is even looked at.
  const std::string lock_path = path + ".lock";
  lock_.fd = ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  TROCAR_THROW_UNLESS(lock_.fd >= 0, lock_path << ": cannot make the database's lock file ("
                                               << std::strerror(errno) << ")");
  if (::flock(lock_.fd, LOCK_EX | LOCK_NB) != 0) {
    TROCAR_THROW_UNLESS(errno != EWOULDBLOCK,
                        path << ": in use by another trocar bench (it holds " << lock_path
                             << "); wait for it to finish, or write to another database");
    TROCAR_THROW(lock_path << ": cannot lock (" << std::strerror(errno) << ")");
  }
  const bool exists = std::filesystem::exists(path);
  if (exists) {
    TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": not a file");
    // Read-only first: a file that is not ours is refused before anything could write to it.
    sqlite3* ro = nullptr;
    std::string error;
    std::set<std::string> tables;
    std::string stored;
    if (sqlite3_open_v2(path.c_str(), &ro, SQLITE_OPEN_READONLY, nullptr) == SQLITE_OK) {
      try {
        tables = Tables(ro, path);
        if (tables.count("trocar_bench")) {
          Statement s(ro, "SELECT value FROM trocar_bench WHERE key='spec'", path);
          if (s.Step()) stored = s.Text(0);
        }
      } catch (const Error& e) {
        error = e.what();
      }
    } else {
      error = sqlite3_errmsg(ro);
    }
    sqlite3_close(ro);
    TROCAR_THROW_UNLESS(error.empty(), path << ": not an SQLite database (" << error
                                            << "); refusing to overwrite it");
    TROCAR_THROW_UNLESS(HasOmplTables(tables),
                        path << ": not an OMPL benchmark database; refusing to overwrite it");
    TROCAR_THROW_UNLESS(tables.count("trocar_bench") && tables.count("trocar_runs"),
                        path << ": an OMPL benchmark database that trocar bench did not make; "
                                "refusing to add to it (write to another database)");
    TROCAR_THROW_UNLESS(stored == spec,
                        path << ": made by trocar bench for another spec; a bench resumes only "
                                "its own spec (write to another database, or restore the spec)");
  }
  if (sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr) !=
      SQLITE_OK) {
    const std::string message = db_ ? sqlite3_errmsg(db_) : "out of memory";
    sqlite3_close(db_);
    db_ = nullptr;
    TROCAR_THROW(path << ": cannot open the database (" << message << ")");
  }
  sqlite3_busy_timeout(db_, 10000);
  Exec("PRAGMA foreign_keys = ON");
  Exec("PRAGMA synchronous = NORMAL");
  if (!exists) {
    Exec(std::string("BEGIN;") + kOmplSchema + kTrocarSchema + "COMMIT;");
    Statement s(db_, "INSERT INTO trocar_bench VALUES ('spec', ?)", path_);
    s.Bind(1, spec).Step();
  }
  Statement s(db_, "SELECT name, type FROM trocar_properties", path_);
  while (s.Step()) column_types_[s.Text(0)] = s.Text(1);
}

BenchDatabase::~BenchDatabase() { sqlite3_close(db_); }

void BenchDatabase::Exec(const std::string& sql) const {
  char* message = nullptr;
  if (sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &message) != SQLITE_OK) {
    const std::string m = message ? message : "unknown error";
    sqlite3_free(message);
    TROCAR_THROW(path_ << ": " << m);
  }
}

int BenchDatabase::Experiment(const ExperimentInfo& info) {
  {
    Statement s(db_, "SELECT id FROM experiments WHERE name = ?", path_);
    s.Bind(1, info.name);
    if (s.Step()) return static_cast<int>(s.Int(0));
  }
  Statement s(db_,
              "INSERT INTO experiments (name, totaltime, timelimit, memorylimit, runcount, "
              "version, hostname, cpuinfo, date, seed, setup) VALUES (?,?,?,?,?,?,?,?,?,?,?)",
              path_);
  s.Bind(1, info.name)
      .Bind(2, 0.0)
      .Bind(3, info.timelimit)
      .Bind(4, info.memorylimit)
      .BindInt(5, info.runcount)
      .Bind(6, std::string("OMPL 1.5.2"))
      .Bind(7, Hostname())
      .Bind(8, std::string(""))
      .Bind(9, Now())
      .Bind(10, std::to_string(info.seed))
      .Bind(11, info.setup)
      .Step();
  return static_cast<int>(sqlite3_last_insert_rowid(db_));
}

int BenchDatabase::PlannerConfig(const std::string& name, const std::string& settings) {
  {
    Statement s(db_, "SELECT id FROM plannerConfigs WHERE name = ? AND settings = ?", path_);
    s.Bind(1, name).Bind(2, settings);
    if (s.Step()) return static_cast<int>(s.Int(0));
  }
  Statement s(db_, "INSERT INTO plannerConfigs (name, settings) VALUES (?, ?)", path_);
  s.Bind(1, name).Bind(2, settings).Step();
  return static_cast<int>(sqlite3_last_insert_rowid(db_));
}

void BenchDatabase::Enum(const std::string& name, const std::vector<std::string>& values) {
  for (std::size_t i = 0; i < values.size(); ++i) {
    Statement s(db_, "INSERT OR IGNORE INTO enums VALUES (?, ?, ?)", path_);
    s.Bind(1, name).BindInt(2, static_cast<long>(i)).Bind(3, values[i]).Step();
  }
}

std::set<std::string> BenchDatabase::DoneKeys() const {
  std::set<std::string> keys;
  Statement s(db_, "SELECT key FROM trocar_runs", path_);
  while (s.Step()) keys.insert(s.Text(0));
  return keys;
}

std::string BenchDatabase::Payload(const std::string& key) const {
  Statement s(db_, "SELECT payload FROM trocar_runs WHERE key = ?", path_);
  s.Bind(1, key);
  return s.Step() ? s.Text(0) : "";
}

void BenchDatabase::AddRun(const std::string& key, int experiment, int planner,
                           const std::vector<RunProperty>& properties, const RunValues& values,
                           const std::string& payload) {
  TROCAR_THROW_UNLESS(properties.size() == values.size(),
                      "run " << key << ": " << values.size() << " values for "
                             << properties.size() << " properties");
  Exec("BEGIN IMMEDIATE");
  try {
    for (const auto& p : properties) {
      const std::string column = ColumnName(p.name);
      const auto it = column_types_.find(column);
      if (it == column_types_.end()) {
        Exec("ALTER TABLE runs ADD " + column + " " + p.type);
        Statement s(db_, "INSERT INTO trocar_properties VALUES (?, ?, ?)", path_);
        s.Bind(1, column).Bind(2, p.type).BindInt(3, static_cast<long>(column_types_.size())).Step();
        column_types_[column] = p.type;
      } else {
        TROCAR_THROW_UNLESS(it->second == p.type, "run property '" << p.name << "' is "
                                                                   << it->second << ", not "
                                                                   << p.type);
      }
    }
    std::string columns = "experimentid, plannerid", marks = "?, ?";
    for (const auto& p : properties) {
      columns += ", " + ColumnName(p.name);
      marks += ", ?";
    }
    Statement s(db_, "INSERT INTO runs (" + columns + ") VALUES (" + marks + ")", path_);
    s.BindInt(1, experiment).BindInt(2, planner);
    for (std::size_t i = 0; i < values.size(); ++i) {
      if (values[i] && std::isfinite(*values[i]))
        s.Bind(static_cast<int>(i) + 3, *values[i]);
      else
        s.BindNull(static_cast<int>(i) + 3);
    }
    s.Step();
    const long run = sqlite3_last_insert_rowid(db_);
    Statement k(db_, "INSERT INTO trocar_runs VALUES (?, ?, ?)", path_);
    k.Bind(1, key).BindInt(2, run).Bind(3, payload).Step();
    Exec("COMMIT");
  } catch (...) {
    sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
    throw;
  }
}

void BenchDatabase::UpdateTotalTimes() {
  std::string sum = "COALESCE(SUM(time), 0)";
  if (column_types_.count("simplification_time"))
    sum += " + COALESCE(SUM(simplification_time), 0)";
  if (!column_types_.count("time")) return;
  Exec("UPDATE experiments SET totaltime = (SELECT " + sum +
       " FROM runs WHERE runs.experimentid = experiments.id)");
}

long BenchDatabase::RunCount() const {
  Statement s(db_, "SELECT COUNT(*) FROM runs", path_);
  s.Step();
  return s.Int(0);
}

std::vector<std::string> BenchDatabase::WriteLogs(const std::string& db_path) const {
  std::vector<std::string> written;
  std::filesystem::path base(db_path);
  base.replace_extension();
  // Property columns in the order they were added.
  std::vector<std::pair<std::string, std::string>> columns;
  {
    Statement s(db_, "SELECT name, type FROM trocar_properties ORDER BY position", path_);
    while (s.Step()) columns.emplace_back(s.Text(0), s.Text(1));
  }
  std::vector<std::string> status_names;
  {
    Statement s(db_, "SELECT description FROM enums WHERE name = 'status' ORDER BY value", path_);
    while (s.Step()) status_names.push_back(s.Text(0));
  }
  Statement experiments(db_,
                        "SELECT id, name, totaltime, timelimit, memorylimit, runcount, hostname, "
                        "date, seed, setup FROM experiments ORDER BY id",
                        path_);
  int k = 0;
  while (experiments.Step()) {
    ++k;
    const long id = experiments.Int(0);
    std::ostringstream log;
    log << "OMPL version 1.5.2\n"
        << "Experiment " << experiments.Text(1) << "\n"
        << "Running on " << experiments.Text(6) << "\n"
        << "Starting at " << experiments.Text(7) << "\n"
        << "<<<|\n"
        << experiments.Text(9) << (experiments.Text(9).empty() ? "" : "\n") << "|>>>\n"
        << "<<<|\n"
        << "|>>>\n"
        << experiments.Text(8) << " is the random seed\n"
        << experiments.Real(3) << " seconds per run\n"
        << experiments.Real(4) << " MB per run\n"
        << experiments.Int(5) << " runs per planner\n"
        << experiments.Real(2) << " seconds spent to collect the data\n";
    if (!status_names.empty()) {
      log << "1 enum type\nstatus";
      for (const auto& n : status_names) log << "|" << n;
      log << "\n";
    }
    std::vector<std::pair<long, std::string>> planners;
    {
      Statement s(db_,
                  "SELECT DISTINCT plannerConfigs.id, plannerConfigs.name, plannerConfigs.settings "
                  "FROM runs JOIN plannerConfigs ON runs.plannerid = plannerConfigs.id WHERE "
                  "runs.experimentid = ? ORDER BY plannerConfigs.id",
                  path_);
      s.BindInt(1, id);
      while (s.Step()) planners.emplace_back(s.Int(0), s.Text(1) + "\n" + s.Text(2));
    }
    log << planners.size() << " planners\n";
    for (const auto& [planner, name_settings] : planners) {
      const std::string name = name_settings.substr(0, name_settings.find('\n'));
      const std::string settings = name_settings.substr(name_settings.find('\n') + 1);
      log << name << "\n";
      // Settings: "name TYPE = value" lines, separated by ';' in the database (as OMPL's parser
      // stores them).
      std::vector<std::string> lines;
      std::istringstream in(settings);
      for (std::string line; std::getline(in, line, ';');) {
        while (!line.empty() && (line.back() == '\n' || line.back() == '\r')) line.pop_back();
        while (!line.empty() && line.front() == '\n') line.erase(line.begin());
        if (!line.empty()) lines.push_back(line);
      }
      log << lines.size() << " common properties\n";
      for (const auto& l : lines) log << l << "\n";
      // Only the properties this experiment's runs have (any non-null value).
      std::vector<std::pair<std::string, std::string>> used;
      for (const auto& [column, type] : columns) {
        Statement s(db_,
                    "SELECT COUNT(*) FROM runs WHERE experimentid = ? AND " + column +
                        " IS NOT NULL",
                    path_);
        s.BindInt(1, id);
        s.Step();
        if (s.Int(0) > 0) used.emplace_back(column, type);
      }
      log << used.size() << " properties for each run\n";
      for (const auto& [column, type] : used) {
        std::string words = column;
        for (char& c : words) {
          if (c == '_') c = ' ';
        }
        log << words << " " << type << "\n";
      }
      std::string select = "SELECT ";
      for (std::size_t c = 0; c < used.size(); ++c) select += (c ? ", " : "") + used[c].first;
      if (used.empty()) select += "id";
      Statement runs(db_,
                     select + " FROM runs WHERE experimentid = ? AND plannerid = ? ORDER BY id",
                     path_);
      runs.BindInt(1, id).BindInt(2, planner);
      std::ostringstream rows;
      long count = 0;
      while (runs.Step()) {
        ++count;
        for (std::size_t c = 0; c < used.size(); ++c) {
          if (!runs.Null(static_cast<int>(c)))
            rows << LogNumber(runs.Real(static_cast<int>(c)), used[c].second);
          rows << "; ";
        }
        rows << "\n";
      }
      log << count << " runs\n" << rows.str() << ".\n";
    }
    const std::string path =
        k == 1 ? base.string() + ".log" : base.string() + "." + std::to_string(k) + ".log";
    WriteFileAtomically(path, log.str());
    written.push_back(path);
  }
  return written;
}

}  // namespace trocar::planners
