#pragma once
/// @file
/// The workstation's 3D scene (VTK): a patient model (skin, bones, heart, other structures),
/// its targets with their approach-normal cones, the candidate port curves, a plan's ports, the
/// table and floor, and a robot drawn from its links' visual shapes (collision shapes where a
/// link has none), or in the meshes its description's `appearance` dresses it in (the bundled da
/// Vinci wears the SurRoL PSM's and ECM's: kinematics/appearance.hpp), posed by a RobotState.
///
/// Every actor belongs to a named *group* ("skin", "ribs", "heart", "target:LAD", "cones",
/// "candidates", "ports", "table", "floor", "robot"), whose colour, opacity and visibility the
/// style sets and the window changes. Flat style draws each group unlit in its exact colour, so
/// that a picture can be checked pixel by pixel (tests) and read by eye as a map of what is where.
///
/// Cameras (thesis §2.10): the external view frames the patient, table and robot; the endoscope
/// view looks from a robot frame along an axis of that frame (the ECM's tool or its 30° camera
/// frame, or any end effector), with a light at the scope tip of adjustable intensity (thesis
/// requirement 2).

#include <map>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "common/image.hpp"
#include "patient/patient_model.hpp"
#include "plan/plan_file.hpp"
#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

class vtkRenderer;
class vtkRenderWindow;

namespace trocar::viz {

/// Colours (RGB 0..1) and opacities per group, and the background. Groups not named take the
/// defaults of their kind ("target:*" → "target", a structure not listed → "organ").
struct SceneStyle {
  std::map<std::string, Eigen::Vector3d> colours;
  std::map<std::string, double> opacities;
  std::map<std::string, bool> visible;
  Eigen::Vector3d background{0.10, 0.11, 0.14};
  /// Unlit, exact colours (no shading): a pixel's colour names its group.
  bool flat = false;
  /// The patient's surfaces are decimated for display to this many triangles in all (0: never):
  /// the default scene draws at 10 fps or more in software rendering (bench/view_bench).
  long patient_triangles = 50000;

  static SceneStyle Default();
  Eigen::Vector3d Colour(const std::string& group) const;
  double Opacity(const std::string& group) const;
  bool Visible(const std::string& group) const;
  /// Sets a colour from "name=r,g,b" (0..1 or 0..255), an opacity from "name=v".
  /// @throws trocar::Error naming the text and what was expected.
  void ParseColour(const std::string& text);
  void ParseOpacity(const std::string& text);
};

/// A camera in the world frame W (m).
struct CameraPose {
  Eigen::Vector3d position = Eigen::Vector3d(2, -2, 2);
  Eigen::Vector3d focal_point = Eigen::Vector3d::Zero();
  Eigen::Vector3d view_up = Eigen::Vector3d::UnitZ();
  double view_angle_deg = 30.0;  ///< vertical field of view
};

/// A camera riding on a robot frame: it looks along `axis_F` of `frame` (an endoscope's view, or
/// an end effector's).
struct FrameCamera {
  std::string frame;
  Eigen::Vector3d axis_F = Eigen::Vector3d::UnitZ();
  double view_angle_deg = 70.0;  ///< the scope's field of view (2 × the plan's half angle)
  double light_intensity = 1.0;  ///< the light at the scope tip
};

/// Whether `window` draws with a software rasteriser (Mesa's llvmpipe, softpipe or swrast: Xvfb or
/// a machine without a GPU), from its OpenGL renderer string; false before its first frame.
bool SoftwareRendering(vtkRenderWindow* window);
/// The same from a window's capabilities text (vtkRenderWindow::ReportCapabilities): its
/// "OpenGL renderer string" line names llvmpipe, softpipe, swrast or a software rasterizer.
bool IsSoftwareRenderer(const std::string& capabilities);

/// Fits an interactive window's drawing to what draws it; call after its first frame. With a
/// software rasteriser, multisampling off: VTK's default of 8 samples cost a frame of the default
/// scene 115 ms instead of 41 under llvmpipe at 1280x720, and 2 or 4 samples cost as much
/// (bench/view_bench; docs/decisions.md, "A window that keeps up"). The pictures
/// (`trocar view --screenshot`) never multisample. With a GPU, kept. Returns true when it turned
/// multisampling off (the next frame shows it).
bool AdaptToRenderer(vtkRenderWindow* window);
/// AdaptToRenderer at the end of the first frame `window` draws, while its context is current
/// (an interactive window's toolkit draws it when it is ready; asked about its renderer before,
/// the Qt window crashed about one run in six).
void AdaptAfterFirstFrame(vtkRenderWindow* window);

class Scene {
 public:
  /// `robot` may be null (a patient alone), and `patient` too (a robot on the floor). @throws trocar::Error for a robot mesh VTK cannot
  /// take (it names the link).
  Scene(std::shared_ptr<const patient::PatientModel> patient,
        std::shared_ptr<const robot::RobotModel> robot, SceneStyle style = SceneStyle::Default());
  ~Scene();
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  const patient::PatientModel* patient() const;
  const robot::RobotModel* robot() const;
  /// Why some of the robot's links are drawn in their own shapes rather than the meshes their
  /// description's `appearance` names (its file missing), one line each.
  const std::vector<std::string>& robot_notes() const;
  const SceneStyle& style() const;

  /// Every group in the scene, in drawing order.
  std::vector<std::string> groups() const;
  void SetColour(const std::string& group, const Eigen::Vector3d& rgb);
  void SetOpacity(const std::string& group, double opacity);
  void SetVisible(const std::string& group, bool visible);
  void SetBackground(const Eigen::Vector3d& rgb);
  void SetFlat(bool flat);

  /// Shows a plan of `file`: its ports (incision and pivot), its target samples' approach cones,
  /// and the robot at its nominal pose. @throws trocar::Error when the plan does not fit the robot.
  void ShowPlan(const planners::PlanFile& file, std::size_t index);
  /// Colours each target along its length by how plan `index` of `file` serves it (issue #43
  /// item 5; planners::TargetReachability): each sample's stretch of the curve (nearer to it
  /// than to its neighbours) drawn over the target in the group "reach:served" (every instrument
  /// moves there and an endoscope sees it), "reach:partly" (some arm does) or "reach:none" (no
  /// instrument moves there). @throws trocar::Error when the plan's data names an unknown arm
  /// or sample.
  void ShowReachability(const planners::PlanFile& file, std::size_t index);
  /// The robot at `state` (link poses from its X_WL).
  void SetRobotState(const robot::RobotState& state);
  const robot::RobotState* robot_state() const;

  /// The teaching pointer (thesis §6.3.3; group "pointer"): its tip at `X_WP`'s origin, its body
  /// along -z; hidden until placed. Every view of the scene shows it.
  void SetPointer(const Eigen::Isometry3d& X_WP, bool visible = true);
  /// Highlights robot links (by index): `colliding` in the "collision" colour, `near` (near
  /// misses) in the "near_miss" colour; the others back to theirs.
  void HighlightLinks(const std::vector<int>& colliding, const std::vector<int>& near = {});

  /// What the external camera frames: the chest (the patient's skin, where the ports are: the
  /// default, so that the patient fills the view), or the room (patient, table and robot).
  /// kTargets: the targets and the ports, from the patient's front (turned toward the ports'
  /// side and the head), the head up; the chest when the patient has no targets. kPorts: the
  /// ports on the chest, close (3 cm of chest around them), from outside over their middle, the
  /// head up; the chest when no plan is shown.
  enum class Framing { kChest, kRoom, kTargets, kPorts };
  /// The external camera, from the side away from the cart, toward the foot end, from above;
  /// image `aspect` = width / height. Without a patient, the room.
  CameraPose ExternalCamera(double aspect, Framing framing = Framing::kChest) const;
  /// The camera on a robot frame at the robot's current state.
  /// @throws trocar::Error when there is no robot state or the frame is unknown.
  CameraPose OnFrame(const FrameCamera& camera) const;

  /// Adds every actor to `renderer` (several renderers of one window may share them) and sets
  /// its background.
  void AddTo(vtkRenderer* renderer) const;
  /// Places `renderer`'s camera; `scope` adds a light at the camera (the scope tip) and turns
  /// the renderer's automatic lights off.
  static void Apply(const CameraPose& pose, vtkRenderer* renderer, const FrameCamera* scope = nullptr);
  /// Leaves out of `renderer` the robot shapes on the link that carries `scope`'s frame (and the
  /// links welded to it) and those whose bounds hold the camera at `pose`, putting back any left
  /// out for another pose before: a camera at a scope's tip does not see the scope it is in (a
  /// worn endoscope mesh reaches past the tip).
  void LeaveOutCarrier(vtkRenderer* renderer, const FrameCamera& scope,
                       const CameraPose& pose) const;

  /// Overlays of an external view (issue #43 item 2): "orientation", a marker of the patient's
  /// head, left and front (arrows and letters in the groups' colours "marker:head",
  /// "marker:left", "marker:anterior"), and "legend", the structures and targets shown with their
  /// colours. Shown unless the style hides them; a flat style (pixel tests) shows them only when
  /// its `visible` names them.
  bool ShowsOverlay(const std::string& name) const;
  /// Draws the orientation marker into `renderer` (a small corner renderer over the view) with
  /// its camera turned as `view`'s, so that its arrows point where the patient's head, left and
  /// front are in that view.
  void AddOrientationMarker(vtkRenderer* renderer, const CameraPose& view) const;
  /// Adds the legend (lower right) to `renderer`: one entry per visible structure, target and
  /// port group, in its colour.
  void AddLegend(vtkRenderer* renderer) const;

  /// Triangles drawn (visible groups).
  long triangle_count() const;
  int actor_count() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// A camera looking along -`direction_W` (from that side) at the middle of `p_W`, far enough
/// that they all fit the view (image `aspect` = width / height), `up_W` up as far as it is
/// across the view. @throws trocar::Error when `p_W` is empty.
CameraPose FramePoints(const std::vector<Eigen::Vector3d>& p_W, double aspect,
                       const Eigen::Vector3d& direction_W, const Eigen::Vector3d& up_W);

/// A base pose from typed values (thesis §2.8): `position` "x, y, z" (m) and `rotation` as XYZ
/// Euler angles "a, b, c" (deg, R = Rx(a) Ry(b) Rz(c)), a quaternion "w, x, y, z" (normalised), or
/// a rotation matrix of 9 numbers by rows (orthonormal within 1e-6, determinant +1).
/// Commas or spaces separate numbers. @throws trocar::Error naming the text and what was expected.
Eigen::Isometry3d ParseBasePose(const std::string& position, const std::string& rotation);
/// XYZ Euler angles (deg) of R = Rx(a) Ry(b) Rz(c).
Eigen::Vector3d EulerXyzDeg(const Eigen::Matrix3d& R);

/// One view of a screenshot or a window pane.
struct ViewSpec {
  enum class Kind { kExternal, kRoom, kTargets, kPorts, kEndoscope, kFrame };
  Kind kind = Kind::kExternal;
  FrameCamera camera;  ///< kEndoscope (from the plan's view) and kFrame
  /// "external" (the chest and its ports), "room" (patient, table and robot), "targets" (the
  /// targets and the ports from the front, Scene::Framing::kTargets), "ports" (the ports on the
  /// chest, close), "endoscope",
  /// "frame:<name>" (along the frame's z axis).
  /// @throws trocar::Error for any other text.
  static ViewSpec Parse(const std::string& text);
};

/// Views with their cameras, drawn side by side (one renderer each, equal widths).
using Views = std::vector<std::pair<ViewSpec, CameraPose>>;

/// Renders `views` into an image of `width` × `height` pixels (rows top to bottom). Needs an X
/// display (Xvfb when headless). @throws trocar::Error when no display is open or the size is
/// out of 16..8192.
Image Render(const Scene& scene, const Views& views, int width, int height);

/// What `window` last drew, `width` × `height` pixels (rows top to bottom).
/// @throws trocar::Error when the window's size is not that.
Image ReadPixels(vtkRenderWindow* window, int width, int height);

/// Render + WritePng.
void Screenshot(const Scene& scene, const Views& views, int width, int height,
                const std::string& path);

/// The camera a view spec gives in `scene` at `aspect`. An endoscope view takes the first view
/// of the shown plan (`views` of the plan file); without one, the frame of an arm whose role is
/// "endoscope". @throws trocar::Error when there is none.
CameraPose ViewCamera(const Scene& scene, const ViewSpec& view, double aspect,
                      const planners::StoredPlan* plan, FrameCamera* used = nullptr);

}  // namespace trocar::viz
