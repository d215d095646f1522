#pragma once
// The bundled da Vinci cart and phantom patient, loaded once per test binary and shared by the
// planners' test files.
#include <memory>

#include "patient/patient_model.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar::planners::test_bundled {

inline std::shared_ptr<const robot::RobotModel> Cart() {
  static auto cart = std::make_shared<const robot::RobotModel>(
      robot::LoadRobot(test::SourcePath("robots/davinci-classic/cart.yaml")));
  return cart;
}

inline std::shared_ptr<const patient::PatientModel> Phantom() {
  static auto patient = std::make_shared<const patient::PatientModel>(
      patient::ImportPatient(test::SourcePath("patients/phantom-default")));
  return patient;
}

}  // namespace trocar::planners::test_bundled
