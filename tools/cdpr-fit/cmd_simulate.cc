// cdpr-fit simulate: a recording of what the TRUE robot's sensors would read at given poses.
#include <sstream>

#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/recording/recording.hpp"
#include "commands.hpp"
#include "common.hpp"

namespace cdpr::fit {

Result<Output> simulate(const SimulateArgs& args) {
  auto truth = load_config(args.config);
  if (!truth.ok()) return truth.status();
  std::optional<CalibratedModel> nominal;
  if (!args.nominal.empty()) {
    auto n = load_config(args.nominal);
    if (!n.ok()) return n.status();
    if (n->num_cables() != truth->num_cables()) {
      return Status::error(
          ErrorCode::kInvalidArgument, "--nominal %s has %d cables but --config %s has %d",
          args.nominal.c_str(), n->num_cables(), args.config.c_str(), truth->num_cables());
    }
    nominal = CalibratedModel::from_robot(*n);
  }
  auto channels = parse_channels(args.channels, *truth, args.config);
  if (!channels.ok()) return channels.status();
  const bool want_laser = channels->laser, want_swivel = channels->swivel,
             want_incl = channels->inclinometer, want_yaw = channels->imu_yaw;
  if (args.elastic && !nominal) {
    return Status(ErrorCode::kInvalidArgument,
                  "--physics elastic needs --nominal (the "
                  "controller's model computes the length commands)");
  }
  Result<recording::PoseList> list = recording::PoseList{};
  std::string poses_source = args.poses;
  if (args.design > 0) {
    PoseDesignOptions design;
    design.num_poses = args.design;
    design.noise = args.noise;
    design.channels = *channels;  // designed for the channels recorded
    fit_estimates_to_channels(design.channels, &design.identification);
    design.progress = console().progress;
    const CalibratedModel planner = nominal ? *nominal : CalibratedModel::from_robot(*truth);
    fit_design_box_to_robot(planner.robot, design);
    auto d = cdpr::design_poses(planner, design);
    if (!d.ok()) return with_context(d.status(), "--design " + std::to_string(args.design));
    list->poses = d->poses;
    poses_source = "design_poses(" + std::to_string(args.design) + ")";
  } else {
    list = recording::read_pose_list(args.poses);
    if (!list.ok()) return list.status();
    CDPR_RETURN_IF_ERROR(recording::check_plausible(*list, *truth, args.poses));
  }

  SimulationOptions options;
  options.physics =
      args.elastic ? SimulationOptions::Physics::kElastic : SimulationOptions::Physics::kRigid;
  options.controller = nominal ? &*nominal : nullptr;
  options.add_noise = args.add_noise;
  options.reference_tension = args.reference_tension;
  options.use_channels(*channels);
  for (const int j : args.reference_poses) {
    if (j < 0 || j >= static_cast<int>(list->poses.size())) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "--reference-poses: pose %d is not in %s (it has %zu poses)", j,
                           poses_source.c_str(), list->poses.size());
    }
    options.reference_pose_indices.push_back(j);
  }
  // Homing: the true robot's encoders are zeroed at the home pose with the controller's model
  // (the nominal one, else the truth), so length_i has the meaning the recording format states
  // (docs/recording-format.md) and an elastic platform commanded home settles at home, where the
  // home-pose gauge of `calibrate` puts row 0.
  const RobotModel& controller = nominal ? nominal->robot : *truth;
  auto homed = homed_truth(*truth, controller, args.reference_tension);
  if (!homed.ok()) return with_context(homed.status(), "simulating " + args.config);
  const CalibratedModel& truth_model = *homed;
  auto sim = simulate_measurements(truth_model, list->poses, args.noise, args.seed, options);
  if (!sim.ok()) {
    // Poses designed for the nominal robot can lie just outside the true robot's workspace: the
    // rigid physics puts the platform exactly there, the elastic one lets it settle.
    // A suspended robot (m < 6) hangs only at equilibrium poses of the TRUE robot.
    const bool hint = !args.elastic &&
                      (sim.status().message().find("wrench-feasible") != std::string_view::npos ||
                       sim.status().message().find("not an equilibrium") != std::string_view::npos);
    return Status::error(sim.status().code(), "simulating %s at the poses of %s: %.*s%s",
                         args.config.c_str(), poses_source.c_str(),
                         static_cast<int>(sim.status().message().size()),
                         sim.status().message().data(),
                         hint ? " (with --physics elastic --nominal the true robot settles near "
                                "each commanded pose instead)"
                              : "");
  }

  recording::Metadata md;
  md.set(recording::key::kFormat, "cdpr-recording 1");
  md.set(recording::key::kUnits, "SI");
  // The robot as the controller knows it (the daemon stamps its own config's name), so that a
  // recording of the measured robot calibrates from the nominal config without a name warning.
  md.set(recording::key::kRobot, nominal ? nominal->robot.name : truth->name);
  md.set("truth_robot", truth->name);
  md.set(recording::key::kDate, recording::utc_timestamp());
  // The config in force while "recording" is the controller's; without one, the truth's.
  const std::string& config_file = args.nominal.empty() ? args.config : args.nominal;
  md.set(recording::key::kConfigFile, config_file);
  md.set(recording::key::kConfigHash, hash_or_unknown(config_file));
  md.set("truth_config", args.config);
  md.set("truth_config_hash", hash_or_unknown(args.config));
  md.set("poses", poses_source);
  md.set(recording::key::kSource, "simulated");
  md.set(recording::key::kSeed, std::to_string(args.seed));
  md.set("physics", args.elastic ? "elastic" : "rigid");
  md.set("noise_added", args.add_noise ? "yes" : "no");
  md.set("homing", "encoder zero at the home pose of " + config_file);
  auto rec = recording::from_measurement_set(sim->set, md);
  if (!rec.ok()) return rec.status();
  CDPR_RETURN_IF_ERROR(recording::write_recording(*rec, args.out));

  Output out;
  out.json = {{"command", "simulate"},
              {"recording", args.out},
              {"config", args.config},
              {"poses", rec->poses.size()},
              {"cables", rec->num_cables},
              {"lasers", rec->num_lasers},
              {"seed", args.seed},
              {"physics", args.elastic ? "elastic" : "rigid"},
              {"noise",
               {{"length_m", args.noise.sigma_length},
                {"force_n", args.noise.sigma_force},
                {"laser_m", args.noise.sigma_laser},
                {"added", args.add_noise}}}};
  // The issue 18 channels only when asked for (the default report is unchanged).
  if (want_swivel || want_incl || want_yaw || !want_laser) {
    out.json["channels"] = args.channels;
    if (want_swivel) out.json["noise"]["swivel_rad"] = args.noise.sigma_swivel;
    if (want_incl) out.json["noise"]["inclination_rad"] = args.noise.sigma_inclination;
    if (want_yaw) out.json["noise"]["imu_yaw_rad"] = args.noise.sigma_imu_yaw;
  }
  std::ostringstream h;
  h << "simulated " << rec->poses.size() << " poses of " << truth->name << " (" << rec->num_cables
    << " cables, " << rec->num_lasers << " laser" << (rec->num_lasers == 1 ? "" : "s") << ", "
    << (args.elastic ? "elastic" : "rigid") << " physics, seed " << args.seed << ")\n"
    << "channels: lengths, tensions" << (want_laser ? ", laser" : "")
    << (want_swivel ? ", swivel angles" : "") << (want_incl ? ", inclinometer" : "")
    << (want_yaw ? ", IMU yaw" : "") << "\n"
    << "noise: length " << args.noise.sigma_length << " m, force " << args.noise.sigma_force
    << " N, laser " << args.noise.sigma_laser << " m" << (args.add_noise ? "" : " (not added)")
    << "\nwrote " << args.out << "\n";
  out.human = h.str();
  return out;
}

}  // namespace cdpr::fit
