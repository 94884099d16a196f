#include "app.hpp"

#include <glog/logging.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdlib>
#include <exception>
#include <functional>
#include <memory>

#include "cdpr/io/output_paths.hpp"
#include "cdpr/report/format.hpp"
#include "cdpr/version.hpp"
#include "commands.hpp"
#include "common.hpp"
#include "progress.hpp"

namespace cdpr::fit {

namespace {

constexpr const char* kFileNote =
    "Files: recordings, experiments and pose lists are CSV (docs/recording-format.md), robot "
    "configs YAML (docs/config.md). SI units throughout.";

// The error document of --json: {"command", "ok": false, "error": {code, message}}.
std::string error_json(const std::string& command, std::string_view code,
                       std::string_view message) {
  const nlohmann::json j = {
      {"command", command},
      {"ok", false},
      {"error", {{"code", std::string(code)}, {"message", std::string(message)}}}};
  return report::json_text(j) + "\n";
}

int run_command(int argc, const char* const* argv, std::ostream& out, std::ostream& err);

}  // namespace

int run(int argc, const char* const* argv, std::ostream& out, std::ostream& err) {
  // Nothing escapes: a bug (an exception we did not expect) is reported and exits kExitInternal,
  // so a script never mistakes it for a result.
  try {
    return run_command(argc, argv, out, err);
  } catch (const std::exception& e) {
    err << "cdpr-fit: internal error: " << e.what() << " (please report it)\n";
  } catch (...) {
    err << "cdpr-fit: internal error: unknown exception (please report it)\n";
  }
  return kExitInternal;
}

namespace {

// The sensor sigmas of calibrate, diagnose and validate (NaN: the recording's).
void add_noise_options(CLI::App* c, NoiseOverrides* n) {
  const std::pair<const char*, double NoiseOverrides::*> options[] = {
      {"--noise-length", &NoiseOverrides::length},
      {"--noise-laser", &NoiseOverrides::laser},
      {"--noise-force", &NoiseOverrides::force},
      {"--noise-swivel", &NoiseOverrides::swivel},
      {"--noise-inclination", &NoiseOverrides::inclination},
      {"--noise-imu-yaw", &NoiseOverrides::imu_yaw},
      {"--noise-ref-position", &NoiseOverrides::reference_position},
      {"--noise-ref-angle", &NoiseOverrides::reference_angle}};
  for (const auto& [name, field] : options) {
    c->add_option(name, n->*field,
                  "sensor sigma replacing the recording's noise_* metadata (m, N or rad)")
        ->check(CLI::PositiveNumber);
  }
}

int run_command(int argc, const char* const* argv, std::ostream& out, std::ostream& err) {
  CLI::App app{"cdpr-fit: offline identification of cable-driven parallel robots"};
  app.footer(kFileNote);
  app.set_version_flag("--version", std::string("cdpr-fit ") + kVersion);
  app.require_subcommand(1);
  app.fallthrough();
  bool json = false;
  bool verbose = false;
  app.add_flag("--json", json, "print the result as JSON on stdout instead of text");
  app.add_flag("-v,--verbose", verbose,
               "\"started\"/\"done\" and the solver's own diagnostics on stderr");
  std::string progress_mode = "auto";
  app.add_option("--progress", progress_mode,
                 "a progress line on stderr for long work (solver iterations, poses designed, "
                 "bootstrap resamples): auto (when stderr is a terminal), always, never")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "always", "never"}));

  std::string command;
  std::function<Result<Output>()> action;
  // The files the command reads and writes: no output may be an input or another output.
  std::vector<io::NamedPath> inputs, outputs;

  // ---- simulate -------------------------------------------------------------------------------
  SimulateArgs sim;
  std::string physics = "rigid";
  bool no_noise = false;
  auto* s = app.add_subcommand("simulate", "write the recording the TRUE robot would give");
  s->add_option("--config", sim.config, "the true robot (YAML)")
      ->required()
      ->check(CLI::ExistingFile);
  auto* sim_poses = s->add_option("--poses", sim.poses, "pose list CSV (pose,x,y,z,roll,pitch,yaw)")
                        ->check(CLI::ExistingFile);
  auto* sim_design =
      s->add_option("--design", sim.design,
                    "instead of --poses: design N poses (D-optimal, home first) on --nominal, "
                    "else on --config")
          ->check(CLI::Range(2, 10000));
  sim_poses->excludes(sim_design);
  sim_design->excludes(sim_poses);
  s->add_option("--nominal", sim.nominal,
                "the controller's model: converts force readings with its sensor calibration and "
                "computes the length commands of --physics elastic")
      ->check(CLI::ExistingFile);
  s->add_option("--noise-laser", sim.noise.sigma_laser, "laser noise std dev, m")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  s->add_option("--noise-length", sim.noise.sigma_length, "cable length noise std dev, m")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  s->add_option("--noise-force", sim.noise.sigma_force, "tension noise std dev, N")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  s->add_option("--noise-ref-position", sim.noise.sigma_reference_position,
                "reference pose position noise std dev, m")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  s->add_option("--noise-ref-angle", sim.noise.sigma_reference_angle,
                "reference pose angle noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  s->add_option("--noise-swivel", sim.noise.sigma_swivel, "swivel angle noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  s->add_option("--noise-inclination", sim.noise.sigma_inclination,
                "inclinometer roll/pitch noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  s->add_option("--noise-imu-yaw", sim.noise.sigma_imu_yaw, "IMU heading noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  s->add_option("--channels", sim.channels,
                "channels besides lengths and tensions, comma-separated: laser, swivel, "
                "inclinometer, imu-yaw (default laser; 'none' for none)")
      ->delimiter(',');
  s->add_flag("--no-noise", no_noise, "write exact readings (the sigmas are still recorded)");
  s->add_option("--seed", sim.seed, "random seed (same seed, same recording)")
      ->capture_default_str();
  s->add_option("--physics", physics,
                "rigid: the platform is at each pose; elastic: the poses are "
                "commands and the elastic robot settles")
      ->capture_default_str()
      ->check(CLI::IsMember({"rigid", "elastic"}));
  s->add_option("--reference-poses", sim.reference_poses,
                "rows (0-based) that also get a reference pose reading, e.g. 0")
      ->delimiter(',');
  s->add_option("--reference-tension", sim.reference_tension, "planned pretension, N")
      ->check(CLI::PositiveNumber);
  s->add_option("--out", sim.out, "recording CSV to write")->required();
  s->callback([&] {
    command = "simulate";
    if (sim.poses.empty() && sim.design == 0) {
      throw CLI::RequiredError("simulate needs --poses FILE or --design N");
    }
    sim.add_noise = !no_noise;
    sim.elastic = physics == "elastic";
    inputs = {{"--config", sim.config}, {"--poses", sim.poses}, {"--nominal", sim.nominal}};
    outputs = {{"--out", sim.out}};
    if (sim.channels.size() == 1 && sim.channels[0] == "none") sim.channels.clear();
    action = [&] { return simulate(sim); };
  });

  // ---- calibrate ------------------------------------------------------------------------------
  CalibrateArgs cal;
  std::string estimate_help =
      "comma-separated parameters to estimate (default: anchors, offsets and the mounting of "
      "each channel the recording has: laser-plane, swivel-zeros, inclinometer-mounting, "
      "imu-yaw-zero); none for a fixed model (only the poses are fitted); any of:";
  for (const std::string& n : estimate_names()) estimate_help += " " + n;
  auto* c = app.add_subcommand("calibrate",
                               "identify the robot from a recording (exit status: 0 passed, 3 fit "
                               "test failed, 4 not trustworthy)");
  c->add_option("--config", cal.config, "nominal robot (YAML): the starting point")
      ->required()
      ->check(CLI::ExistingFile);
  c->add_option("--recording", cal.recording, "recording CSV")
      ->required()
      ->check(CLI::ExistingFile);
  c->add_option("--method", cal.method, "identification method")
      ->capture_default_str()
      ->check(CLI::IsMember({"ours", "paper"}));
  c->add_option("--estimate", cal.estimate, estimate_help)->delimiter(',');
  c->add_option("--gauge", cal.gauge,
                "what fixes the world frame: home, start (the --home-pose row at its commanded "
                "pose), laser-plane, both, none")
      ->capture_default_str();
  c->add_option("--home-pose", cal.home_pose, "row (0-based) of the home pose for --gauge home")
      ->capture_default_str();
  c->add_option("--loss", cal.loss, "robust loss: none, huber, cauchy")->capture_default_str();
  c->add_option("--max-iterations", cal.max_iterations, "solver iterations")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  c->add_option("--out", cal.out, "calibrated robot config to write (YAML)");
  c->add_option("--report", cal.report, "JSON report to write");
  c->add_option("--fit-alpha", cal.fit_alpha,
                "significance level of the chi-square fit test (reject when p is below it)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  c->add_option("--truth", cal.truth,
                "true robot (simulation studies): report the frame anchor errors before and after")
      ->check(CLI::ExistingFile);
  c->add_option("--validate", cal.validate,
                "held-out recording: exit 5 when the calibrated model does not predict it better "
                "than --config")
      ->check(CLI::ExistingFile);
  add_noise_options(c, &cal.noise);
  c->callback([&] {
    command = "calibrate";
    inputs = {{"--config", cal.config},
              {"--recording", cal.recording},
              {"--truth", cal.truth},
              {"--validate", cal.validate}};
    outputs = {{"--out", cal.out}, {"--report", cal.report}};
    action = [&] { return calibrate(cal); };
  });

  // ---- design-poses, predict-accuracy ----------------------------------------------------------
  DesignArgs design;
  auto* dp = app.add_subcommand("design-poses", "choose calibration poses (D-optimal, home first)");
  dp->add_option("--config", design.config, "robot (YAML)")->required()->check(CLI::ExistingFile);
  dp->add_option("--count", design.count, "number of poses, home included")
      ->capture_default_str()
      ->check(CLI::Range(2, 10000));
  dp->add_option("--out", design.out, "pose list CSV to write")->required();
  dp->add_option("--estimate", design.estimate, "parameters the design is for (as calibrate)")
      ->delimiter(',');
  dp->add_option("--half-extent", design.half_extent,
                 "half side of the candidate cube around home, m (default: 0.4 x the frame's "
                 "half extent per axis)")
      ->check(CLI::PositiveNumber);
  dp->add_option("--criterion", design.criterion,
                 "d-optimal (information about the parameters) or position (platform position "
                 "accuracy over the test cube)")
      ->capture_default_str()
      ->check(CLI::IsMember({"d-optimal", "position"}));
  dp->add_option("--test-half-extent", design.test_half_extent,
                 "half side of the test cube for --criterion position and --compare, m")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  dp->add_option(
        "--points-per-axis", design.points_per_axis,
        "candidate grid points per axis (1 + 6 x --angle-steps orientations each; above 12 "
        "the design takes minutes and a warning says so)")
      ->capture_default_str()
      ->check(CLI::Range(2, 20));
  dp->add_option("--max-angle", design.max_angle, "candidate orientations up to this angle, rad")
      ->capture_default_str();
  dp->add_option(
        "--angle-steps", design.angle_steps,
        "candidate tilts about each axis: max-angle x j / N, j = 1..N (a robot that cannot "
        "tilt the full angle about one axis still tilts part of it)")
      ->capture_default_str()
      ->check(CLI::Range(1, 6));
  dp->add_option("--emphasis-weight", design.emphasis_weight,
                 "weight of the laser's beam direction (a tilted mount, which diagnose tests) in "
                 "the design, beside the estimated parameters; 0: plain D-optimal")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  dp->add_option(
        "--tension-margin", design.tension_margin,
        "keep every pose's cable tensions this far inside [f_min, f_max], N (cdprd designs "
        "with 10 N, measuring.design_tension_margin; a tilted pose at the workspace edge "
        "may overload the real robot, whose geometry is not the nominal one)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  dp->add_option("--noise-laser", design.noise.sigma_laser, "laser noise std dev, m")
      ->capture_default_str();
  dp->add_option("--noise-length", design.noise.sigma_length, "length noise std dev, m")
      ->capture_default_str();
  dp->add_option("--noise-force", design.noise.sigma_force, "tension noise std dev, N")
      ->capture_default_str();
  dp->add_option("--noise-swivel", design.noise.sigma_swivel, "swivel angle noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  dp->add_option("--noise-inclination", design.noise.sigma_inclination,
                 "inclinometer roll/pitch noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  dp->add_option("--noise-imu-yaw", design.noise.sigma_imu_yaw, "IMU heading noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  dp->add_option("--channels", design.channels,
                 "channels the calibration records besides lengths and tensions, "
                 "comma-separated: laser, swivel, inclinometer, imu-yaw, or none (default: laser "
                 "when the config has one)")
      ->delimiter(',');
  dp->add_flag("--compare", design.compare,
               "also predict the accuracy of random and box-corner sets of the same size");
  dp->add_option("--seed", design.seed, "seed of the random comparison set")->capture_default_str();
  dp->callback([&] {
    command = "design-poses";
    inputs = {{"--config", design.config}};
    outputs = {{"--out", design.out}};
    action = [&] { return design_poses(design); };
  });

  PredictArgs predict;
  auto* pa = app.add_subcommand(
      "predict-accuracy", "Cramer-Rao bounds and position error of calibrating at given poses");
  pa->add_option("--config", predict.config, "robot (YAML)")->required()->check(CLI::ExistingFile);
  pa->add_option("--poses", predict.poses, "pose list CSV")->required()->check(CLI::ExistingFile);
  pa->add_option("--estimate", predict.estimate, "parameters (as calibrate)")->delimiter(',');
  pa->add_option("--noise-laser", predict.noise.sigma_laser, "laser noise std dev, m")
      ->capture_default_str();
  pa->add_option("--noise-length", predict.noise.sigma_length, "length noise std dev, m")
      ->capture_default_str();
  pa->add_option("--noise-force", predict.noise.sigma_force, "tension noise std dev, N")
      ->capture_default_str();
  pa->add_option("--noise-swivel", predict.noise.sigma_swivel, "swivel angle noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  pa->add_option("--noise-inclination", predict.noise.sigma_inclination,
                 "inclinometer roll/pitch noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  pa->add_option("--noise-imu-yaw", predict.noise.sigma_imu_yaw, "IMU heading noise std dev, rad")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  pa->add_option("--channels", predict.channels,
                 "channels the calibration records besides lengths and tensions, "
                 "comma-separated: laser, swivel, inclinometer, imu-yaw, or none (default: laser "
                 "when the config has one)")
      ->delimiter(',');
  pa->add_option("--half-extent", predict.half_extent, "half side of the test cube, m")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  pa->add_option("--points-per-axis", predict.points_per_axis, "test grid points per axis")
      ->capture_default_str()
      ->check(CLI::Range(2, 50));
  pa->callback([&] {
    command = "predict-accuracy";
    action = [&] { return predict_accuracy(predict); };
  });

  // ---- fit-cable ------------------------------------------------------------------------------
  FitCableArgs cable;
  auto* fc = app.add_subcommand("fit-cable", "fit the elongation surface dL = f(L, F) of a cable");
  fc->add_option("--experiment", cable.experiment, "cable experiment CSV")
      ->required()
      ->check(CLI::ExistingFile);
  fc->add_option("--min-order", cable.min_order, "lowest candidate order")
      ->capture_default_str()
      ->check(CLI::Range(0, 8));
  fc->add_option("--max-order", cable.max_order, "highest candidate order")
      ->capture_default_str()
      ->check(CLI::Range(0, 8));
  fc->add_option("--folds", cable.folds, "K of K-fold cross-validation")
      ->capture_default_str()
      ->check(CLI::Range(2, 1000));
  fc->add_option("--seed", cable.seed, "fold shuffling seed")->capture_default_str();
  fc->add_flag("--minimum-error", cable.minimum_error,
               "choose the order of least CV error (default: one-standard-error rule)");
  fc->callback([&] {
    command = "fit-cable";
    action = [&] { return fit_cable(cable); };
  });

  // ---- fit-force-sensor -----------------------------------------------------------------------
  FitForceArgs force;
  auto* ff = app.add_subcommand("fit-force-sensor", "fit gain and offset of each force sensor");
  ff->add_option("--experiment", force.experiment, "force-sensor experiment CSV")
      ->required()
      ->check(CLI::ExistingFile);
  ff->add_option("--gravity", force.gravity, "g, m/s^2 (default: the file's gravity_m_s2, 9.81)")
      ->check(CLI::PositiveNumber);
  ff->callback([&] {
    command = "fit-force-sensor";
    action = [&] { return fit_force_sensor(force); };
  });

  // ---- diagnose -------------------------------------------------------------------------------
  DiagnoseArgs diag;
  std::string diag_json;
  auto* dg = app.add_subcommand(
      "diagnose",
      "find where the model and a recording disagree and name the missing physics (exit status: "
      "0 no mismatch, 3 mismatch found, 4 inconclusive)");
  dg->add_option("--config", diag.config, "nominal robot (YAML)")
      ->required()
      ->check(CLI::ExistingFile);
  dg->add_option("--recording", diag.recording, "recording CSV")
      ->required()
      ->check(CLI::ExistingFile);
  dg->add_option("--validate", diag.validate,
                 "second recording of the same robot for held-out prediction (else K-fold CV)")
      ->check(CLI::ExistingFile);
  auto* dg_json = dg->add_option("--json", diag_json,
                                 "JSON report: to FILE, or on stdout instead of the text when "
                                 "given without a value or as '-'")
                      ->expected(0, 1);
  dg->add_option("--html", diag.html, "HTML report to write (one self-contained file)");
  dg->add_option("--out", diag.out, "calibrated config carrying the named effects (YAML)");
  dg->add_option("--estimate", diag.estimate,
                 "parameters of the standard identification (as calibrate --estimate)")
      ->delimiter(',');
  add_noise_options(dg, &diag.noise);
  dg->add_option("--gauge", diag.gauge, "as calibrate --gauge")->capture_default_str();
  dg->add_option("--home-pose", diag.home_pose, "as calibrate --home-pose")->capture_default_str();
  dg->add_option("--seed", diag.seed, "seed of the bootstrap and the folds")->capture_default_str();
  dg->add_option("--bootstrap", diag.bootstrap, "bootstrap resamples over poses")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  dg->add_option("--folds", diag.folds,
                 "cross-validation over poses: 0 leaves one pose out, K >= 2 K folds")
      ->capture_default_str()
      ->check(CLI::Validator(
          [](std::string& v) {
            char* end = nullptr;
            const long k = std::strtol(v.c_str(), &end, 10);
            const bool ok = end != v.c_str() && *end == '\0' && (k == 0 || (k >= 2 && k <= 100000));
            return ok ? std::string() : "must be 0 (leave one pose out) or 2 to 100000";
          },
          "0 or 2..100000"));
  dg->callback([&] {
    command = "diagnose";
    if (dg_json->count() > 0) {
      if (diag_json.empty() || diag_json == "-") {
        json = true;
      } else {
        diag.json_report = diag_json;
      }
    }
    inputs = {
        {"--config", diag.config}, {"--recording", diag.recording}, {"--validate", diag.validate}};
    outputs = {{"--out", diag.out}, {"--json", diag.json_report}, {"--html", diag.html}};
    action = [&] { return diagnose(diag); };
  });

  // ---- validate -------------------------------------------------------------------------------
  ValidateArgs val;
  auto* va = app.add_subcommand(
      "validate", "models predicting a held-out recording (poses re-fitted, each model fixed)");
  va->add_option("--config", val.config, "the config the recording was made with (its readings)")
      ->required()
      ->check(CLI::ExistingFile);
  va->add_option("--recording", val.recording, "held-out recording CSV")
      ->required()
      ->check(CLI::ExistingFile);
  va->add_option("--model", val.models, "a model to compare (repeat: nominal, calibrated, ...)")
      ->required()
      ->check(CLI::ExistingFile);
  add_noise_options(va, &val.noise);
  va->callback([&] {
    command = "validate";
    inputs = {{"--config", val.config}, {"--recording", val.recording}};
    action = [&] { return validate_models(val); };
  });

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e, out, err);
    return code == 0 ? 0 : kExitUsage;
  }
  if (Status paths = io::check_output_paths(inputs, outputs); !paths.ok()) {
    err << "cdpr-fit " << command << ": error: " << paths.message() << "\n";
    if (json) out << error_json(command, to_string(paths.code()), paths.message());
    return kExitUsage;
  }

  // Ceres reports evaluation trouble through glog (dozens of lines per residual block, and an
  // ERROR line when a diagnosis tries an alternative effect whose fit cannot be evaluated, which
  // diagnose handles): only with -v. The reason reaches the user as the command's one-line error.
  FLAGS_minloglevel = verbose ? google::GLOG_INFO : google::GLOG_FATAL;
  auto sink = std::make_shared<spdlog::sinks::ostream_sink_mt>(err);
  spdlog::logger log("cdpr-fit", sink);
  log.set_pattern("cdpr-fit: %v");
  log.set_level(verbose ? spdlog::level::info : spdlog::level::warn);
  log.info("{} started", command);
  ProgressLine progress(err, progress_wanted(progress_mode, err));
  console().progress = progress.callback();
  console().warn = [&](const std::string& w) {
    progress.finish();
    err << "cdpr-fit " << command << ": warning: " << w << "\n";
  };
  const auto t0 = std::chrono::steady_clock::now();
  Result<Output> result = action();
  progress.finish();
  console() = Console{};
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!result.ok()) {
    const Status& st = result.status();
    err << "cdpr-fit " << command << ": error: " << st.message() << "\n";
    if (json) out << error_json(command, to_string(st.code()), st.message());
    return kExitFailed;
  }
  log.info("{} done in {:.3f} s", command, seconds);
  if (!result->notice.empty()) err << result->notice;
  if (json) {
    result->json["ok"] = true;
    out << report::json_text(result->json) << "\n";
  } else {
    out << result->human;
  }
  out.flush();
  return result->exit_status;
}

}  // namespace

}  // namespace cdpr::fit
