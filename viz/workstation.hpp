#pragma once
/// @file
/// The surgeon's workstation window (Qt 5 with VTK's QVTKOpenGLNativeWidget, as the thesis'
/// simulator and 3D Slicer): a sidebar with the ranked plans (score breakdown, verdict,
/// verification), the patient structures (visibility, opacity), the robot (cart pose by typed
/// values, every active joint by a slider) and the views (scope light, layout, a camera riding on
/// any robot frame); the external view and the endoscope view side by side.
/// Mouse (thesis §2.10): left rotate, right pan, middle or wheel zoom.

#include <memory>
#include <optional>
#include <string>

#include "plan/plan_file.hpp"
#include "scene.hpp"
#include "view_inputs.hpp"

class vtkInteractorStyle;

namespace trocar::viz {

struct WorkstationOptions {
  ViewInputs inputs;   ///< what the view was opened from (saved in scene files)
  int plan_index = 0;  ///< 0-based
  std::optional<CameraPose> camera;  ///< the external view's camera (default: framed)
  /// Render, save an image of the whole window (sidebar and views) to this PNG, and close:
  /// the window as a user sees it, for tests and documentation.
  std::string grab_path;
  int width = 1400, height = 820;
};

/// Opens the window and runs until it is closed. Errors while it runs (a plan that does not fit
/// the robot, a joint the robot refuses) are shown in the window and on stderr; the window stays.
/// @return the exit code (0). @throws trocar::Error when no display can be opened.
int RunWorkstation(std::unique_ptr<Scene> scene, std::shared_ptr<const robot::RobotModel> robot,
                   const planners::PlanFile* plan, const WorkstationOptions& options);

/// The sidebar's page for plan `index` (0-based) of `file`, as HTML: its ports in a surgeon's
/// terms, the score's terms with units and weights, its verification, the verdict that counts
/// (by verified motions) and the claimed one, each labelled, and its sign-off status.
/// @throws trocar::Error when the index is out of range.
std::string PlanPageHtml(const planners::PlanFile& file, std::size_t index);

/// The thesis' mouse mapping (§2.10) over VTK's trackball camera: left button rotates, right
/// pans, middle or wheel zooms.
vtkInteractorStyle* NewThesisCameraStyle();

}  // namespace trocar::viz
