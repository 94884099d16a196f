// cdpr-fit design-poses and predict-accuracy: planning a calibration before measuring.
#include <cmath>
#include <sstream>

#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/recording/recording.hpp"
#include "commands.hpp"
#include "common.hpp"

namespace cdpr::fit {

namespace {

// Above this --points-per-axis (7 x 12^3 = 12,096 candidates) design-poses warns before it starts.
constexpr int kSlowPointsPerAxis = 12;

nlohmann::json poses_json(const std::vector<Pose>& poses) {
  nlohmann::json a = nlohmann::json::array();
  for (const Pose& p : poses) a.push_back(to_json(Eigen::VectorXd(p.vector())));
  return a;
}

// The channels of a plan (--channels; none given: the laser when the config has one) and the
// parameters it is for: without --estimate the defaults fitted to the channels (as calibrate
// fits them to a recording's columns), with --estimate checked against the channels.
Status plan_channels(const std::vector<std::string>& words,
                     const std::vector<std::string>& estimate, const RobotModel& robot,
                     const std::string& config, SensorChannels* channels,
                     IdentificationOptions* identification) {
  if (words.empty()) {
    *channels = SensorChannels{};
    channels->laser = !robot.lasers.empty();
  } else {
    auto c = parse_channels(words, robot, config);
    if (!c.ok()) return c.status();
    *channels = *c;
  }
  CDPR_RETURN_IF_ERROR(apply_estimate(estimate, robot.num_cables(), identification));
  if (estimate.empty()) fit_estimates_to_channels(*channels, identification);
  if (Status s = check_estimates_for_channels(robot, *channels, *identification); !s.ok()) {
    return Status(ErrorCode::kInvalidArgument,
                  "--estimate names laser parameters but --channels has no laser: they would "
                  "stay unobserved");
  }
  return Status::success();
}

// The channels as JSON words and their noise (only the channels used).
nlohmann::json channel_words(const SensorChannels& c) {
  nlohmann::json a = nlohmann::json::array();
  if (c.laser) a.push_back("laser");
  if (c.swivel) a.push_back("swivel");
  if (c.inclinometer) a.push_back("inclinometer");
  if (c.imu_yaw) a.push_back("imu-yaw");
  return a;
}

nlohmann::json noise_json(const SensorNoise& n, const SensorChannels& c) {
  nlohmann::json j = {{"length_m", n.sigma_length}, {"force_n", n.sigma_force}};
  if (c.laser) j["laser_m"] = n.sigma_laser;
  if (c.swivel) j["swivel_rad"] = n.sigma_swivel;
  if (c.inclinometer) j["inclination_rad"] = n.sigma_inclination;
  if (c.imu_yaw) j["imu_yaw_rad"] = n.sigma_imu_yaw;
  return j;
}

// The --estimate words of the emphasised parameter kinds ("laser-direction").
std::vector<std::string> emphasis_words(const std::vector<ParameterKind>& kinds) {
  std::vector<std::string> out;
  for (ParameterKind kind : kinds) {
    if (const EstimateItem* e = estimate_item_of(kind)) out.emplace_back(e->word);
  }
  return out;
}

}  // namespace

Result<Output> design_poses(const DesignArgs& args) {
  auto model = load_config(args.config);
  if (!model.ok()) return model.status();
  PoseDesignOptions options;
  options.num_poses = args.count;
  if (std::isnan(args.half_extent)) {
    fit_design_box_to_robot(*model, options);
  } else {
    options.center = model->home.position;
    options.half_extent = Eigen::Vector3d::Constant(args.half_extent);
  }
  AccuracyBox test_box;
  test_box.center = model->home.position;
  test_box.half_extent = Eigen::Vector3d::Constant(args.test_half_extent);
  options.accuracy_box = test_box;
  if (args.criterion == "position") options.criterion = DesignCriterion::kPositionAccuracy;
  options.points_per_axis = args.points_per_axis;
  options.progress = console().progress;
  if (args.points_per_axis > kSlowPointsPerAxis) {
    const long candidates = (1L + 6L * args.angle_steps) * args.points_per_axis *
                            args.points_per_axis * args.points_per_axis;
    console().warn("--points-per-axis " + std::to_string(args.points_per_axis) + " gives " +
                   std::to_string(candidates) +
                   " candidate poses: the design takes minutes and gigabytes");
  }
  options.max_angle = args.max_angle;
  options.angle_steps = args.angle_steps;
  options.emphasis_weight = args.emphasis_weight;
  options.tension_margin = args.tension_margin;
  options.noise = args.noise;
  CDPR_RETURN_IF_ERROR(plan_channels(args.channels, args.estimate, *model, args.config,
                                     &options.channels, &options.identification));
  const CalibratedModel cm = CalibratedModel::from_robot(*model);
  auto design = cdpr::design_poses(cm, options);
  if (!design.ok()) return with_context(design.status(), "designing poses for " + args.config);

  recording::PoseList list;
  list.metadata.set(recording::key::kRobot, model->name);
  list.metadata.set(recording::key::kDate, recording::utc_timestamp());
  list.metadata.set(recording::key::kConfigFile, args.config);
  list.metadata.set(recording::key::kConfigHash, hash_or_unknown(args.config));
  list.metadata.set(recording::key::kSource,
                    options.criterion == DesignCriterion::kPositionAccuracy
                        ? "cdpr-fit design-poses (position accuracy, home first)"
                        : "cdpr-fit design-poses (D-optimal, home first)");
  list.poses = design->poses;
  const std::vector<std::string> emphasised = emphasis_words(design->emphasised);
  CDPR_RETURN_IF_ERROR(recording::write_pose_list(list, args.out));

  Output out;
  out.json = {{"command", "design-poses"},
              {"config", args.config},
              {"out", args.out},
              {"count", design->poses.size()},
              {"estimate", estimated_items(options.identification)},
              {"channels", channel_words(options.channels)},
              {"noise", noise_json(options.noise, options.channels)},
              {"candidates", design->candidates},
              {"max_angle_rad", options.max_angle},
              {"angle_steps", options.angle_steps},
              {"emphasis", emphasised},
              {"emphasis_weight", options.emphasis_weight},
              {"emphasis_log_det", design->emphasis_log_det},
              {"tension_margin_n", options.tension_margin},
              {"exchanges", design->exchanges},
              {"criterion", args.criterion},
              {"candidate_half_extent_m", to_json(Eigen::VectorXd(options.half_extent))},
              {"log_det", design->log_det},
              {"path_length", design->path_length},
              {"poses", poses_json(design->poses)}};
  std::ostringstream h;
  h << "designed " << design->poses.size() << " poses for " << model->name << " ("
    << design->candidates << " feasible candidates, " << design->exchanges << " exchanges, log det "
    << fmt(design->log_det, 6) << ", path " << fmt(design->path_length, 4) << " m)\nestimating:";
  for (const std::string& e : estimated_items(options.identification)) h << " " << e;
  for (const std::string& e : emphasised) {
    h << "\nalso designed to see: " << e << " (weight " << fmt(options.emphasis_weight, 3)
      << ", log det " << fmt(design->emphasis_log_det, 4) << ")";
  }
  h << "\nchannels: lengths, tensions"
    << (options.channels.words() == "none" ? "" : ", " + options.channels.words());
  h << "\ncandidate box: +-" << fmt(options.half_extent.x(), 3) << " x "
    << fmt(options.half_extent.y(), 3) << " x " << fmt(options.half_extent.z(), 3)
    << " m around home, tilted up to " << fmt(options.max_angle, 4) << " rad";
  if (options.tension_margin > 0.0) {
    h << ", tensions kept " << fmt(options.tension_margin, 3) << " N inside the limits";
  }
  h << "; criterion " << args.criterion;
  if (options.criterion == DesignCriterion::kPositionAccuracy) {
    h << " (predicted position RMS over the test cube " << fmt(1e3 * design->position_rms_m, 3)
      << " mm, D-optimal start " << fmt(1e3 * design->position_rms_d_optimal_m, 3) << " mm)";
    out.json["position_rms_m"] = design->position_rms_m;
    out.json["position_rms_d_optimal_m"] = design->position_rms_d_optimal_m;
  }
  h << "\nwrote " << args.out << "\n";
  if (args.compare) {
    auto cmp = compare_pose_sets(cm, options, test_box, args.seed);
    if (!cmp.ok()) return with_context(cmp.status(), "comparing pose sets");
    nlohmann::json rows = nlohmann::json::array();
    h << "\npredicted accuracy (same size sets):\n"
      << "  set                    poses   anchor std (m)   position RMS (m)   condition\n";
    for (const PoseSetComparison& c : *cmp) {
      rows.push_back({{"label", c.label},
                      {"poses", c.num_poses},
                      {"anchor_rms_std_m", c.anchor_rms_std_m},
                      {"position_rms_m", c.position_rms_m},
                      {"condition_number", number_or_null(c.condition_number)}});
      char line[160];
      std::snprintf(line, sizeof line, "  %-20s %7d   %14.3e   %16.3e   %9.3g\n", c.label.c_str(),
                    c.num_poses, c.anchor_rms_std_m, c.position_rms_m, c.condition_number);
      h << line;
    }
    out.json["comparison"] = rows;
  }
  out.human = h.str();
  return out;
}

Result<Output> predict_accuracy(const PredictArgs& args) {
  auto model = load_config(args.config);
  if (!model.ok()) return model.status();
  auto list = recording::read_pose_list(args.poses);
  if (!list.ok()) return list.status();
  PredictedAccuracyOptions options;
  CDPR_RETURN_IF_ERROR(plan_channels(args.channels, args.estimate, *model, args.config,
                                     &options.channels, &options.identification));
  options.box.center = model->home.position;
  options.box.half_extent = Eigen::Vector3d::Constant(args.half_extent);
  options.box.points_per_axis = args.points_per_axis;
  auto p =
      cdpr::predict_accuracy(CalibratedModel::from_robot(*model), list->poses, args.noise, options);
  if (!p.ok()) {
    return with_context(p.status(), "predicting the accuracy of " + args.poses);
  }
  nlohmann::json params = nlohmann::json::array();
  std::ostringstream h;
  h << "predicted accuracy of calibrating " << model->name << " at the " << list->poses.size()
    << " poses of " << args.poses << "\n(channels: lengths, tensions"
    << (options.channels.words() == "none" ? "" : ", " + options.channels.words())
    << "; noise: length " << args.noise.sigma_length << " m, force " << args.noise.sigma_force
    << " N";
  if (options.channels.laser) h << ", laser " << args.noise.sigma_laser << " m";
  if (options.channels.swivel) h << ", swivel " << args.noise.sigma_swivel << " rad";
  if (options.channels.inclinometer) {
    h << ", inclinometer " << args.noise.sigma_inclination << " rad";
  }
  if (options.channels.imu_yaw) h << ", IMU yaw " << args.noise.sigma_imu_yaw << " rad";
  h << ")\n\n  parameter                  CRB std\n";
  for (std::size_t i = 0; i < p->names.size(); ++i) {
    const double sd = i < static_cast<std::size_t>(p->crb_std.size())
                          ? p->crb_std(static_cast<Eigen::Index>(i))
                          : std::numeric_limits<double>::quiet_NaN();
    params.push_back({{"name", p->names[i]}, {"crb_std", number_or_null(sd)}});
    char line[128];
    std::snprintf(line, sizeof line, "  %-24s %10.3e\n", p->names[i].c_str(), sd);
    h << line;
  }
  h << "\nrank " << p->rank << " of " << p->names.size() << "\nanchor RMS std "
    << fmt(p->anchor_rms_std_m, 3) << " m\nposition error over the " << p->grid_points
    << "-point test grid (cube of half side " << args.half_extent << " m): RMS "
    << fmt(p->position_rms_m, 3) << " m, max " << fmt(p->position_max_m, 3) << " m\n";
  if (model->suspended && model->num_cables() < 6) {
    h << "(suspended robot: each grid target evaluated where the platform hangs at its position "
         "and heading)\n";
  }
  if (p->skipped_points > 0) {
    h << p->skipped_points << " grid targets skipped (tensions out of limits, or cannot hang)\n";
  }
  Output out;
  out.json = {{"command", "predict-accuracy"},
              {"config", args.config},
              {"poses", args.poses},
              {"pose_count", list->poses.size()},
              {"estimate", estimated_items(options.identification)},
              {"channels", channel_words(options.channels)},
              {"noise", noise_json(args.noise, options.channels)},
              {"parameters", params},
              {"rank", p->rank},
              {"anchor_rms_std_m", p->anchor_rms_std_m},
              {"position_rms_m", p->position_rms_m},
              {"position_max_m", p->position_max_m},
              {"grid_points", p->grid_points}};
  out.human = h.str();
  return out;
}

}  // namespace cdpr::fit
