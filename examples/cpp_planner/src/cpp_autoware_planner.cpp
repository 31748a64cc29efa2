// A planner node as a C++ Autoware team writes one: an rclcpp node on a 10 Hz timer under
// `use_sim_time`, Autoware's messages in and out, nothing of advperc_ros linked or included.
// The C++ counterpart of examples/autoware_planner.py; attack it with:
//
//   ros2 run cpp_planner cpp_autoware_planner     # in one terminal, then in another:
//   ros2 launch advperc_ros attack.launch.py params:=config/idm_lane_following.yaml
//       planner:=external interface:=autoware drive:=clock   (one line; same ROS_DOMAIN_ID)
//
// Inputs: autoware_perception_msgs/PredictedObjects on /perception/object_recognition/objects,
// nav_msgs/Odometry on /localization/kinematic_state (in this graph the pose is the centre of the
// ego's box, not Autoware's rear axle) and the route as a latched nav_msgs/Path on /ego/route (the
// graph has no Lanelet2 map). Output: autoware_planning_msgs/Trajectory on
// /planning/scenario_planning/trajectory, sampled every metre along the route from 2 m behind the
// ego, `time_from_start` left 0 as Autoware's planners leave it, the speed in
// `longitudinal_velocity_mps`. It announces its build on the latched /attack/nodes (optional), so
// the attack's report says which version of it was attacked.
//
// Under the graph's clock (docs/stacks.md, "Driving the planner") the node does what it does on a
// car: plan on every tick with the latest inputs it holds, stamp the trajectory with the clock's
// time, and take a jump of the clock back as a restart. The planning itself is a placeholder, an
// adaptive cruise control along the route: cruise at the speed limit, follow the nearest predicted
// object ahead within the lane at a time gap.

#include <unistd.h>  // getpid

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <autoware_perception_msgs/msg/predicted_objects.hpp>
#include <autoware_planning_msgs/msg/trajectory.hpp>
#include <nav_msgs/msg/odometry.hpp>
#include <nav_msgs/msg/path.hpp>
#include <rclcpp/rclcpp.hpp>
#include <std_msgs/msg/string.hpp>

namespace cpp_planner
{

using autoware_perception_msgs::msg::PredictedObjects;
using autoware_planning_msgs::msg::Trajectory;
using autoware_planning_msgs::msg::TrajectoryPoint;
using nav_msgs::msg::Odometry;
using nav_msgs::msg::Path;

// this build: the attack's report names it and its config_hash covers it
constexpr char kVersion[] = "cpp-acc-0.1";
constexpr std::chrono::milliseconds kPeriod{100};
constexpr double kPeriodS = 0.1;
constexpr double kHorizonS = 8.0;
constexpr double kSampleM = 1.0;
constexpr double kBehindM = 2.0;
constexpr double kSpeedLimit = 14.0;  // m/s
constexpr double kTimeGapS = 1.4;
constexpr double kStandstillM = 4.0;  // bumper to bumper
constexpr double kMaxAccel = 1.5;  // m/s^2
constexpr double kMaxDecel = 6.0;  // m/s^2
constexpr double kEgoLengthM = 4.6;
constexpr double kLaneHalfWidthM = 1.8;

// Per-frame topics: reliable, volatile, the last 10 kept (what the graph's writers match).
rclcpp::QoS reliable_qos() {return rclcpp::QoS(rclcpp::KeepLast(10)).reliable().durability_volatile();}
// Latched topics (/ego/route, /attack/nodes): transient local, so a node started late still gets them.
rclcpp::QoS latched_qos() {return rclcpp::QoS(rclcpp::KeepLast(1)).reliable().transient_local();}

double yaw_of(const geometry_msgs::msg::Quaternion & q)
{
  return std::atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z));
}

// np.interp: piecewise linear through (xs, ys), xs increasing, held constant beyond either end.
double interpolate(double x, const std::vector<double> & xs, const std::vector<double> & ys)
{
  if (x <= xs.front()) {return ys.front();}
  if (x >= xs.back()) {return ys.back();}
  const auto j = static_cast<std::size_t>(std::upper_bound(xs.begin(), xs.end(), x) - xs.begin()) - 1;
  return ys[j] + (ys[j + 1] - ys[j]) * (x - xs[j]) / (xs[j + 1] - xs[j]);
}

// The route as a polyline with arc lengths: projection and interpolation along it.
class Route
{
public:
  struct Pose2D
  {
    double x, y, heading;
  };

  explicit Route(const Path & path)
  {
    for (const auto & stamped : path.poses) {
      const double x = stamped.pose.position.x;
      const double y = stamped.pose.position.y;
      // repeated points would make zero-length segments, which have no heading
      if (!s_.empty() && std::hypot(x - x_.back(), y - y_.back()) <= 1e-6) {continue;}
      s_.push_back(s_.empty() ? 0.0 : s_.back() + std::hypot(x - x_.back(), y - y_.back()));
      x_.push_back(x);
      y_.push_back(y);
    }
  }

  // a route needs one segment at least
  bool valid() const {return s_.size() >= 2;}

  // (arc length, signed lateral offset, left positive) of a point's foot on the route
  std::pair<double, double> project(double x, double y) const
  {
    double best_distance = std::numeric_limits<double>::infinity();
    std::size_t best = 0;
    double best_u = 0.0;
    for (std::size_t i = 0; i + 1 < s_.size(); ++i) {
      const double dx = x_[i + 1] - x_[i];
      const double dy = y_[i + 1] - y_[i];
      const double u = std::clamp(((x - x_[i]) * dx + (y - y_[i]) * dy) / (dx * dx + dy * dy), 0.0, 1.0);
      const double distance = std::hypot(x_[i] + u * dx - x, y_[i] + u * dy - y);
      if (distance < best_distance) {  // the first segment of the nearest feet, as np.argmin
        best_distance = distance;
        best = i;
        best_u = u;
      }
    }
    const double dx = x_[best + 1] - x_[best];
    const double dy = y_[best + 1] - y_[best];
    const double length = std::hypot(dx, dy);
    const double lateral = (dx * (y - y_[best]) - dy * (x - x_[best])) / length;
    return {s_[best] + best_u * length, lateral};
  }

  // x, y and heading at arc length s (the ends extended along their segments)
  Pose2D pose(double s) const
  {
    // the segment starting at the last vertex before s, clamped to the first and the last segment
    const auto after = std::lower_bound(s_.begin(), s_.end(), s) - s_.begin();
    const auto i = static_cast<std::size_t>(
      std::clamp<std::ptrdiff_t>(after - 1, 0, static_cast<std::ptrdiff_t>(s_.size()) - 2));
    const double dx = x_[i + 1] - x_[i];
    const double dy = y_[i + 1] - y_[i];
    const double u = (s - s_[i]) / (s_[i + 1] - s_[i]);
    return {x_[i] + u * dx, y_[i] + u * dy, std::atan2(dy, dx)};
  }

private:
  std::vector<double> x_, y_, s_;
};

// A guard condition whose trigger runs a callback from the executor, as rclpy's
// `node.create_guard_condition(callback)` does: rclcpp::GuardCondition alone only wakes a wait set,
// so this Waitable puts it in the node's wait set and runs the callback when it was triggered.
class GuardConditionCallback : public rclcpp::Waitable
{
public:
  explicit GuardConditionCallback(std::function<void()> callback)
  : callback_(std::move(callback)) {}

  // thread-safe: may be called from any callback, the clock's jump callbacks included
  void trigger() {guard_condition_.trigger();}

  std::size_t get_number_of_ready_guard_conditions() override {return 1;}

  void add_to_wait_set(rcl_wait_set_t & wait_set) override {guard_condition_.add_to_wait_set(wait_set);}

  bool is_ready(const rcl_wait_set_t & wait_set) override
  {
    // rcl_wait leaves the triggered guard conditions in the wait set and nulls the others
    for (std::size_t i = 0; i < wait_set.size_of_guard_conditions; ++i) {
      if (wait_set.guard_conditions[i] == &guard_condition_.get_rcl_guard_condition()) {return true;}
    }
    return false;
  }

  std::shared_ptr<void> take_data() override {return nullptr;}  // a trigger carries no data

  std::shared_ptr<void> take_data_by_entity_id(std::size_t) override {return nullptr;}

  void execute(const std::shared_ptr<void> &) override {callback_();}

private:
  rclcpp::GuardCondition guard_condition_;
  std::function<void()> callback_;
};

class CppAutowarePlanner : public rclcpp::Node
{
public:
  CppAutowarePlanner()
  : Node("cpp_autoware_planner", rclcpp::NodeOptions()
      .parameter_overrides({rclcpp::Parameter("use_sim_time", true)})
      // rclcpp's default takes /clock on a thread of its own, where a step of the clock can make the
      // timer ready in the same wait as the frame's inputs, and the executor runs timers first: the
      // plan then uses the previous frame's inputs (2 of 3 attacks were not reproduced so, against 5
      // of 5 with the option off: docs/stacks.md). Taken by this node's own single-threaded
      // executor (as rclpy does), /clock makes the timer ready only after the callbacks of the wait
      // that took it, and the frame's inputs, which came before the clock, were in that wait or earlier.
      .use_clock_thread(false))
  {
    trajectory_pub_ = create_publisher<Trajectory>("/planning/scenario_planning/trajectory", reliable_qos());
    route_sub_ = create_subscription<Path>(
      "/ego/route", latched_qos(), [this](Path::ConstSharedPtr msg) {
        Route route(*msg);
        if (route.valid()) {route_ = std::move(route);}
      });
    odometry_sub_ = create_subscription<Odometry>(
      "/localization/kinematic_state", reliable_qos(), [this](Odometry::ConstSharedPtr msg) {odometry_ = msg;});
    objects_sub_ = create_subscription<PredictedObjects>(
      "/perception/object_recognition/objects", reliable_qos(),
      [this](PredictedObjects::ConstSharedPtr msg) {objects_ = msg;});
    // on the node's clock, which is the simulated one
    timer_ = create_timer(kPeriod, [this]() {on_timer();});

    // optional: say which build this is, on the latched /attack/nodes (the node's name as the ROS
    // graph shows it, and the process id); a plain identifier and version need no JSON escaping
    presence_pub_ = create_publisher<std_msgs::msg::String>("/attack/nodes", latched_qos());
    std_msgs::msg::String presence;
    presence.data = std::string(R"({"node": ")") + get_name() + R"(", "pid": )" + std::to_string(getpid()) +
      R"(, "version": ")" + kVersion + R"("})";
    presence_pub_->publish(presence);

    // A jump of the clock back is a restart (an attack starts every rollout with one), as for any
    // ROS node: tf clears its buffer on one. ROS timers do not fire on a jump back, so the restart
    // plans once the executor has run the callbacks of the inputs that came before the jump: the
    // jump callback, which runs inside /clock's subscription callback (maybe before the others of its
    // wait), only triggers a guard condition, whose callback the executor runs from the next wait.
    restart_ = std::make_shared<GuardConditionCallback>([this]() {on_timer();});
    get_node_waitables_interface()->add_waitable(restart_, nullptr);
    rcl_jump_threshold_t backward{};
    backward.on_clock_change = false;
    backward.min_forward.nanoseconds = 0;  // 0: forward jumps are not reported
    backward.min_backward.nanoseconds = -1;  // every jump back, however small
    jump_handler_ = get_clock()->create_jump_callback(
      nullptr, [this](const rcl_time_jump_t &) {restart_->trigger();}, backward);
  }

private:
  void on_timer()
  {
    const rclcpp::Time now = get_clock()->now();
    if (!route_ || !odometry_ || !objects_) {return;}
    trajectory_pub_->publish(plan(now));
  }

  // (bumper-to-bumper gap, speed along the route) of the nearest object ahead in the lane
  std::optional<std::pair<double, double>> lead(double s_ego) const
  {
    std::optional<std::pair<double, double>> best;
    for (const auto & object : objects_->objects) {
      const auto & pose = object.kinematics.initial_pose_with_covariance.pose;
      const auto [s, lateral] = route_->project(pose.position.x, pose.position.y);
      if (s <= s_ego || std::abs(lateral) > kLaneHalfWidthM) {continue;}
      const double heading = route_->pose(s).heading;
      // Autoware's twist is in the object's own frame: x is its speed forward
      const double speed = object.kinematics.initial_twist_with_covariance.twist.linear.x *
        std::cos(yaw_of(pose.orientation) - heading);
      const double gap = s - s_ego - (kEgoLengthM + object.shape.dimensions.x) / 2.0;
      if (!best || gap < best->first) {best = std::make_pair(gap, speed);}
    }
    return best;
  }

  Trajectory plan(const rclcpp::Time & stamp) const
  {
    const auto & ego = odometry_->pose.pose.position;
    const double s_ego = route_->project(ego.x, ego.y).first;
    double v = std::max(odometry_->twist.twist.linear.x, 0.0);
    // speed profile over the horizon: ACC on the lead (moving at its current speed), else cruise
    const auto lead_object = lead(s_ego);
    double gap = lead_object ? lead_object->first : std::numeric_limits<double>::infinity();
    const double lead_speed = lead_object ? lead_object->second : 0.0;
    double s = s_ego;
    std::vector<double> profile_s{s_ego}, profile_v{v};
    const auto steps = static_cast<int>(kHorizonS / kPeriodS);
    for (int k = 0; k < steps; ++k) {
      double accel = std::isfinite(gap) ?
        0.3 * (gap - kStandstillM - kTimeGapS * v) + 0.8 * (lead_speed - v) :
        0.5 * (kSpeedLimit - v);
      accel = std::clamp(accel, -kMaxDecel, kMaxAccel);
      const double v_next = std::max(v + accel * kPeriodS, 0.0);
      const double step = 0.5 * (v + v_next) * kPeriodS;
      if (step <= 0.0) {break;}  // stopped: the points beyond carry speed 0
      s += step;
      gap += lead_speed * kPeriodS - step;
      v = v_next;
      profile_s.push_back(s);
      profile_v.push_back(v);
    }

    Trajectory trajectory;
    trajectory.header.stamp = stamp;
    trajectory.header.frame_id = "map";
    // every metre from behind the ego to the end of the profile (np.arange's points)
    const double first = s_ego - kBehindM;
    const double end = std::max(profile_s.back(), s_ego) + kSampleM;
    const auto count = static_cast<std::size_t>(std::ceil((end - first) / kSampleM));
    for (std::size_t k = 0; k < count; ++k) {
      const double s_point = first + static_cast<double>(k) * kSampleM;
      const auto pose = route_->pose(s_point);
      TrajectoryPoint point;
      point.pose.position.x = pose.x;
      point.pose.position.y = pose.y;
      point.pose.orientation.z = std::sin(pose.heading / 2.0);
      point.pose.orientation.w = std::cos(pose.heading / 2.0);
      point.longitudinal_velocity_mps = static_cast<float>(interpolate(s_point, profile_s, profile_v));
      trajectory.points.push_back(point);  // time_from_start left 0: the reader times it by the speeds
    }
    return trajectory;
  }

  std::optional<Route> route_;
  Odometry::ConstSharedPtr odometry_;
  PredictedObjects::ConstSharedPtr objects_;
  rclcpp::Publisher<Trajectory>::SharedPtr trajectory_pub_;
  rclcpp::Publisher<std_msgs::msg::String>::SharedPtr presence_pub_;
  rclcpp::Subscription<Path>::SharedPtr route_sub_;
  rclcpp::Subscription<Odometry>::SharedPtr odometry_sub_;
  rclcpp::Subscription<PredictedObjects>::SharedPtr objects_sub_;
  rclcpp::TimerBase::SharedPtr timer_;
  std::shared_ptr<GuardConditionCallback> restart_;
  rclcpp::JumpHandler::SharedPtr jump_handler_;  // the jump callback lives as long as its handler
};

}  // namespace cpp_planner

int main(int argc, char ** argv)
{
  rclcpp::init(argc, argv);
  // rclcpp::spin's executor is single-threaded: the determinism above relies on that
  rclcpp::spin(std::make_shared<cpp_planner::CppAutowarePlanner>());
  rclcpp::shutdown();
  return 0;
}
