#pragma once
/// @file
/// Subcommands of the `trocar` executable; each registers itself on the top-level app.

#include <CLI/CLI.hpp>
#include <map>
#include <ostream>
#include <string>

#include "common/error.hpp"
#include "motion/verify.hpp"

namespace trocar::apps {

/// `trocar robot info FILE`, `trocar robot fk FILE q1 … qn`.
void AddRobotCommand(CLI::App* app);

/// `trocar teleop --robot R --input sinusoid|circle|step|roll|FILE.csv ...`.
void AddTeleopCommand(CLI::App* app);

/// `trocar device --connect ADDRESS:PORT --input circle ...`: an OpenIGTLink device.
void AddDeviceCommand(CLI::App* app);

/// `trocar tune --robot R --controller jt [--save]`: gain auto-tuning.
void AddTuneCommand(CLI::App* app);

/// `trocar phantom --out DIR --seed N ...`.
void AddPatientCommands(CLI::App* app);

/// `trocar check [--patient DIR] [--port F=x,y,z] [--base x y deg] [--q ...]`: collisions and
/// clearances of a robot configuration at a patient.
void AddCheckCommand(CLI::App* app);

/// `trocar plan CASE --out DIR [...]`: ports and cart pose by optimisation.
void AddPlanCommand(CLI::App* app);

/// `trocar bench SPEC.yaml --out DB`, `trocar bench --summary DB`.
void AddBenchCommand(CLI::App* app);

/// `trocar verify PLAN.json`: verified motions for a plan's ranked plans.
void AddVerifyCommand(CLI::App* app);

/// `trocar view CASE [PLAN.json]`: the workstation window, or --screenshot FILE.png.
void AddViewCommand(CLI::App* app);
/// `trocar report PLAN.json --out DIR`: a self-contained HTML report.
void AddReportCommand(CLI::App* app);

/// `trocar signoff PLAN.json --plan K --approve|--reject --surgeon NAME [--note T] [--session F]`.
void AddSignOffCommand(CLI::App* app);

/// Re-checks every claim of a plan file (trocar check --plan); prints what fails.
/// @return 0 when every claim holds, 3 otherwise. @throws trocar::Error for a malformed file.
int CheckPlanFile(const std::string& path, std::ostream& out);

/// The motion options of `plan` and `verify` (--planner, --motion-time, --motion-seed,
/// --motion-threads).
void AddMotionOptions(CLI::App* cmd, planners::MotionOptions* options, int* threads);
/// Runs `check` (a library's option check); a trocar::OptionError it throws is said with the
/// command line's flag for the option: `flags` maps the library's field name to the flag, any
/// other field reads as "--" and its name with '-' for '_' (issue #45 item 3: the libraries name
/// their fields, the CLI its flags). The message's problem part is the library's.
template <typename Check>
void WithFlags(const std::map<std::string, std::string>& flags, Check&& check) {
  try {
    check();
  } catch (const OptionError& e) {
    std::string flag;
    if (const auto it = flags.find(e.option()); it != flags.end()) {
      flag = it->second;
    } else {
      flag = "--" + e.option();
      for (char& c : flag) c = c == '_' ? '-' : c;
    }
    throw Error(flag + ": " + e.problem());
  }
}
/// The flags of the motion options' fields (AddMotionOptions).
const std::map<std::string, std::string>& MotionFlags();

/// A plan's verification in a few lines: motions verified, served share, main failures.
void PrintVerification(const planners::PlanVerification& verification, std::ostream& out);

}  // namespace trocar::apps
