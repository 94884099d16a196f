#include "cdpr/calibration/catenary.hpp"

#include <ceres/jet.h>
#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace cdpr {
namespace {

TEST(Catenary, SolverRecoversTheEndForces) {
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int k = 0; k < 200; ++k) {
    const double l0 = 0.5 + 15.0 * u(rng);
    const double w = 0.01 + 2.0 * u(rng);
    const double ea = 1e4 + 1e6 * u(rng);
    const double h = 1.0 + 500.0 * u(rng);
    const double v = (2.0 * u(rng) - 0.5) * 400.0;
    const Eigen::Vector2d p = elastic_catenary_end_point<double>(h, v, l0, w, ea);
    const Result<CatenarySolution> s = solve_elastic_catenary(p(0), p(1), l0, w, ea);
    ASSERT_TRUE(s.ok()) << s.status().to_string();
    EXPECT_NEAR(s->horizontal_force, h, 1e-7 * (h + std::abs(v))) << k;
    EXPECT_NEAR(s->vertical_force_b, v, 1e-7 * (h + std::abs(v))) << k;
    EXPECT_NEAR(s->vertical_force_a, v - w * l0, 1e-7 * (h + std::abs(v)));
    // The reported solution reproduces the end point.
    const Eigen::Vector2d q =
        elastic_catenary_end_point<double>(s->horizontal_force, s->vertical_force_b, l0, w, ea);
    EXPECT_LT((q - p).norm(), 1e-11 * (1.0 + p.norm()));
  }
}

TEST(Catenary, LevelEndsCarryHalfTheWeightEach) {
  const double l0 = 10.0;
  const double w = 0.2;
  const Result<CatenarySolution> s = solve_elastic_catenary(9.5, 0.0, l0, w, 1e5);
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  EXPECT_NEAR(s->vertical_force_b, 0.5 * w * l0, 1e-10);
  EXPECT_NEAR(s->vertical_force_a, -0.5 * w * l0, 1e-10);
  EXPECT_NEAR(s->tension_a, s->tension_b, 1e-10);
}

TEST(Catenary, InextensibleLimitIsTheClassicCatenary) {
  // span = 2 (H / w) asinh(w L0 / (2 H)) for level ends and EA -> infinity.
  const double l0 = 5.0;
  const double w = 1.0;
  const double h = 7.0;
  const double span = 2.0 * (h / w) * std::asinh(w * l0 / (2.0 * h));
  const Result<CatenarySolution> s = solve_elastic_catenary(span, 0.0, l0, w, 1e14);
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  EXPECT_NEAR(s->horizontal_force, h, 1e-6);
  EXPECT_NEAR(s->stretched_length, l0, 1e-9);
}

TEST(Catenary, StretchedLengthIsTheIntegralOfStrain) {
  // Numerically integrate T(s) / EA along the unstretched arc and compare.
  const double l0 = 3.0;
  const double w = 0.5;
  const double ea = 2e4;
  const Result<CatenarySolution> s = solve_elastic_catenary(2.5, 1.2, l0, w, ea);
  ASSERT_TRUE(s.ok());
  const int n = 20000;
  double stretch = 0.0;
  for (int k = 0; k < n; ++k) {
    const double s0 = (k + 0.5) * l0 / n;
    const double vert = s->vertical_force_a + w * s0;
    stretch += std::hypot(s->horizontal_force, vert) / ea * (l0 / n);
  }
  EXPECT_NEAR(s->stretched_length, l0 + stretch, 1e-10);
  EXPECT_GE(s->stretched_length, s->chord);
}

// Taut cables: exact arc - chord agrees with w^2 l_h^2 c / (24 T^2).
TEST(Catenary, SmallSagApproximationAgreesForTautCables) {
  struct Case {
    double span, height, weight, ea, tension;
  };
  // MINI-like (1.5 mm Dyneema, 0.0015 kg/m) and large-robot-like (0.02 kg/m, 10 m spans).
  const Case cases[] = {{0.55, 0.40, 0.0015 * 9.81, 2e4, 20.0},
                        {0.45, -0.39, 0.0015 * 9.81, 2e4, 5.0},
                        {9.0, 4.0, 0.02 * 9.81, 3e5, 200.0},
                        {12.0, -2.0, 0.02 * 9.81, 3e5, 50.0}};
  for (const Case& c : cases) {
    const double chord = std::hypot(c.span, c.height);
    // Unstretched length for about the wanted tension (straight elastic cable).
    const double l0 = chord / (1.0 + c.tension / c.ea);
    const Result<CatenarySolution> s = solve_elastic_catenary(c.span, c.height, l0, c.weight, c.ea);
    ASSERT_TRUE(s.ok()) << s.status().to_string();
    const double mean_tension = 0.5 * (s->tension_a + s->tension_b);
    // Taut: near the straight-cable tension (sag takes up some length and adds a little).
    EXPECT_NEAR(mean_tension / c.tension, 1.0, 0.5);
    // Arc minus chord: the stretched length is the arc.
    const double exact = s->stretched_length - chord;
    const double approx = sag_arc_minus_chord(c.weight, c.span, chord, mean_tension);
    EXPECT_GT(exact, 0.0);
    EXPECT_NEAR(exact / approx, 1.0, 0.02) << "span " << c.span << " exact " << exact;
  }
}

TEST(Catenary, RefusesBadInput) {
  EXPECT_EQ(solve_elastic_catenary(0.0, 1.0, 1.0, 0.1, 1e4).status().code(),
            ErrorCode::kInvalidArgument);
  EXPECT_EQ(solve_elastic_catenary(1.0, 0.0, -1.0, 0.1, 1e4).status().code(),
            ErrorCode::kInvalidArgument);
  // Weightless and slack: no solution.
  EXPECT_EQ(solve_elastic_catenary(1.0, 0.0, 1.5, 0.0, 1e4).status().code(),
            ErrorCode::kInvalidArgument);
  // Weightless and taut: the straight elastic cable.
  const Result<CatenarySolution> s = solve_elastic_catenary(1.0, 0.0, 0.99, 0.0, 1e4);
  ASSERT_TRUE(s.ok());
  EXPECT_NEAR(s->tension_b, 1e4 * 0.01 / 0.99, 1e-9);
}

TEST(Catenary, EndPointDifferentiatesThroughJet) {
  using Jet = ceres::Jet<double, 2>;
  const double l0 = 4.0, w = 0.3, ea = 5e4, h = 60.0, v = 10.0;
  const Eigen::Matrix<Jet, 2, 1> p =
      elastic_catenary_end_point<Jet>(Jet(h, 0), Jet(v, 1), Jet(l0), Jet(w), Jet(ea));
  const double e = 1e-5;
  const Eigen::Vector2d dh = (elastic_catenary_end_point<double>(h + e, v, l0, w, ea) -
                              elastic_catenary_end_point<double>(h - e, v, l0, w, ea)) /
                             (2 * e);
  const Eigen::Vector2d dv = (elastic_catenary_end_point<double>(h, v + e, l0, w, ea) -
                              elastic_catenary_end_point<double>(h, v - e, l0, w, ea)) /
                             (2 * e);
  for (int k = 0; k < 2; ++k) {
    EXPECT_NEAR(p(k).v(0), dh(k), 1e-8);
    EXPECT_NEAR(p(k).v(1), dv(k), 1e-8);
  }
}

}  // namespace
}  // namespace cdpr
