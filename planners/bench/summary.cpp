// trocar bench --summary: statistics and distribution plots read back from an OMPL benchmark
// database with plain SQL (any database in OMPL's schema, not only trocar's).
#include <sqlite3.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <map>
#include <set>
#include <sstream>

#include "bench/database.hpp"
#include "bench/runner.hpp"
#include "common/error.hpp"
#include "common/geometry.hpp"
#include "common/file_util.hpp"
#include "common/plot.hpp"

namespace trocar::planners {

namespace {

struct Db {
  explicit Db(const std::string& path) : path(path) {
    if (sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) != SQLITE_OK) {
      const std::string m = sqlite3_errmsg(db);
      sqlite3_close(db);
      TROCAR_THROW(path << ": " << m);
    }
  }
  ~Db() { sqlite3_close(db); }
  // Rows of a query, each column as text ("" for NULL) with a NULL flag.
  std::vector<std::vector<std::optional<std::string>>> Rows(const std::string& sql) const {
    sqlite3_stmt* s = nullptr;
    if (sqlite3_prepare_v2(db, sql.c_str(), -1, &s, nullptr) != SQLITE_OK) {
      const std::string m = sqlite3_errmsg(db);
      TROCAR_THROW(path << ": " << m);
    }
    std::vector<std::vector<std::optional<std::string>>> rows;
    int rc;
    while ((rc = sqlite3_step(s)) == SQLITE_ROW) {
      std::vector<std::optional<std::string>> row;
      for (int c = 0; c < sqlite3_column_count(s); ++c) {
        if (sqlite3_column_type(s, c) == SQLITE_NULL)
          row.emplace_back(std::nullopt);
        else
          row.emplace_back(reinterpret_cast<const char*>(sqlite3_column_text(s, c)));
      }
      rows.push_back(row);
    }
    sqlite3_finalize(s);
    TROCAR_THROW_UNLESS(rc == SQLITE_DONE, path << ": " << sqlite3_errmsg(db));
    return rows;
  }
  std::string path;
  sqlite3* db = nullptr;
};

// Share of all runs whose value is at most x, over the sorted values of the solved runs: the
// curve Planner Arena's "solved within" plots show.
PlotSeries Cumulative(const std::string& label, std::vector<double> values, long runs,
                      std::array<std::uint8_t, 3> rgb) {
  std::sort(values.begin(), values.end());
  PlotSeries s;
  s.label = label;
  s.rgb = rgb;
  s.x.push_back(values.empty() ? 0.0 : values.front());
  s.y.push_back(0.0);
  for (std::size_t i = 0; i < values.size(); ++i) {
    s.x.push_back(values[i]);
    s.y.push_back(100.0 * (i + 1) / std::max<long>(runs, 1));
  }
  return s;
}

}  // namespace

std::string BenchSummary(const std::string& db_path, const std::string& plots_dir) {
  BenchDatabase::CheckIsOmplDatabase(db_path);
  const Db db(db_path);
  std::set<std::string> columns;
  for (const auto& row : db.Rows("PRAGMA table_info(runs)")) columns.insert(row[1].value_or(""));
  const bool has_solved = columns.count("solved"), has_time = columns.count("time");
  const std::string length_column = columns.count("simplified_solution_length")
                                        ? "simplified_solution_length"
                                        : (columns.count("solution_length") ? "solution_length" : "");
  std::ostringstream out;
  out << std::fixed;
  if (!plots_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(plots_dir, ec);
    TROCAR_THROW_UNLESS(std::filesystem::is_directory(plots_dir),
                        plots_dir << ": cannot make the plots folder");
  }
  const std::array<std::array<std::uint8_t, 3>, 8> colours = {{{31, 119, 180},
                                                               {255, 127, 14},
                                                               {44, 160, 44},
                                                               {214, 39, 40},
                                                               {148, 103, 189},
                                                               {140, 86, 75},
                                                               {227, 119, 194},
                                                               {127, 127, 127}}};
  for (const auto& e : db.Rows("SELECT id, name FROM experiments ORDER BY id")) {
    const std::string id = e[0].value_or("0"), name = e[1].value_or("");
    out << "experiment " << name << "\n";
    out << "  " << std::left << std::setw(34) << "planner" << std::right << std::setw(6) << "runs"
        << std::setw(10) << "solved %" << std::setw(14) << "median time s" << std::setw(16)
        << "median length" << (columns.count("score") ? "    median score" : "") << "\n";
    PlotPanel times, lengths;
    times.title = name + ": runs solved within a time";
    times.x_label = "time (s)";
    times.y_label = "solved (% of runs)";
    lengths.title = name + ": runs solved with a path at most this long";
    lengths.x_label = "path length (joint space)";
    lengths.y_label = "solved (% of runs)";
    int k = 0;
    for (const auto& p : db.Rows(
             "SELECT DISTINCT plannerConfigs.id, plannerConfigs.name FROM runs JOIN plannerConfigs "
             "ON runs.plannerid = plannerConfigs.id WHERE runs.experimentid = " +
             id + " ORDER BY plannerConfigs.id")) {
      const std::string pid = p[0].value_or("0"), pname = p[1].value_or("");
      std::string select = "SELECT " + std::string(has_solved ? "solved" : "NULL") + ", " +
                           (has_time ? "time" : "NULL") + ", " +
                           (length_column.empty() ? "NULL" : length_column) + ", " +
                           (columns.count("score") ? "score" : "NULL") +
                           " FROM runs WHERE experimentid = " + id + " AND plannerid = " + pid;
      long runs = 0, solved = 0;
      std::vector<double> solved_times, solved_lengths, scores, all_times;
      for (const auto& r : db.Rows(select)) {
        ++runs;
        const bool ok = r[0] && std::stod(*r[0]) != 0.0;
        solved += ok;
        if (r[1]) all_times.push_back(std::stod(*r[1]));
        if (ok && r[1]) solved_times.push_back(std::stod(*r[1]));
        if (ok && r[2]) solved_lengths.push_back(std::stod(*r[2]));
        if (r[3]) scores.push_back(std::stod(*r[3]));
      }
      std::string label = pname;
      for (const std::string prefix : {"geometric_", "portplacement_"}) {
        if (label.rfind(prefix, 0) == 0) label = label.substr(prefix.size());
      }
      out << "  " << std::left << std::setw(34) << label << std::right << std::setw(6) << runs
          << std::setw(10) << std::setprecision(1) << (runs ? 100.0 * solved / runs : 0.0)
          << std::setw(14) << std::setprecision(4) << Median(all_times) << std::setw(16)
          << std::setprecision(3) << Median(solved_lengths);
      if (columns.count("score")) out << std::setw(16) << std::setprecision(3) << Median(scores);
      out << "\n";
      const auto colour = colours[k++ % colours.size()];
      times.series.push_back(Cumulative(label, solved_times, runs, colour));
      if (!solved_lengths.empty())
        lengths.series.push_back(Cumulative(label, solved_lengths, runs, colour));
    }
    if (!plots_dir.empty() && !times.series.empty()) {
      std::vector<PlotPanel> panels = {times};
      if (!lengths.series.empty()) panels.push_back(lengths);
      std::string safe = name;  // a name from any database: never a path
      for (char& c : safe) {
        if (!std::isalnum(static_cast<unsigned char>(c)) && c != '-' && c != '+' && c != '.')
          c = '_';
      }
      const std::string file = JoinPath(plots_dir, (safe.empty() ? "experiment" : safe) + ".png");
      WritePlot(file, panels);
      out << "  plot: " << file << "\n";
    }
  }
  return out.str();
}

}  // namespace trocar::planners
