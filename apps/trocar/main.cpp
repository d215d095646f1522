// trocar: port placement and surgeon verification for robot-assisted minimally invasive surgery.
#include <CLI/CLI.hpp>
#include <iostream>
#include <new>
#include <string>

#include "apps/trocar/commands.hpp"
#include "common/error.hpp"

int main(int argc, char** argv) {
  CLI::App app{"trocar: plans ports and robot placement for robotic minimally invasive surgery"};
  app.require_subcommand(1);
  trocar::apps::AddRobotCommand(&app);
  trocar::apps::AddTeleopCommand(&app);
  trocar::apps::AddDeviceCommand(&app);
  trocar::apps::AddTuneCommand(&app);
  trocar::apps::AddPatientCommands(&app);
  trocar::apps::AddCheckCommand(&app);
  trocar::apps::AddPlanCommand(&app);
  trocar::apps::AddVerifyCommand(&app);
  trocar::apps::AddBenchCommand(&app);
  trocar::apps::AddViewCommand(&app);
  trocar::apps::AddReportCommand(&app);
  trocar::apps::AddSignOffCommand(&app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const trocar::Error& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  } catch (const std::bad_alloc&) {
    // Input too large for this machine: the readers bound what one file may cost
    // (common/limits.hpp); what remains is the whole job's size.
    std::string command;
    for (int i = 1; i < argc; ++i) command += std::string(i > 1 ? " " : "") + argv[i];
    std::cerr << "error: out of memory running 'trocar " << command
              << "': the inputs need more memory than this machine has (lower the phantom's or "
                 "the CT's resolution, or the limits TROCAR_MAX_VOXELS / TROCAR_MAX_FILE_BYTES)\n";
    return 1;
  } catch (const trocar::InternalError& e) {
    std::cerr << "internal error: " << e.what()
              << " (a fault in trocar, not in the input: please report it with the command)\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "internal error: " << e.what() << "\n";
    return 2;
  }
  return 0;
}
