// Each stage of the inversion (lib/src/inversion/) on its own, against answers known without it:
// the swarm on a function with a known global minimum (through its BatchCost interface, no
// forward solver), the Levenberg-Marquardt polish on least-squares problems with known solutions,
// the covariance and the HAC factor in closed form (linear-Gaussian model, AR(1) residuals), the
// start-conflict statistic's chi-square law, the start estimate on a free oscillation from a
// known state (reference integrator), the derived quantities of closed-form force histories, and
// the stream's start decision.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <optional>
#include <random>
#include <span>
#include <vector>

#include "cpu_step.hpp"
#include "inversion/covariance.hpp"
#include "inversion/derived_quantities.hpp"
#include "inversion/levenberg_marquardt.hpp"
#include "inversion/parameter_prior.hpp"
#include "inversion/start_estimate.hpp"
#include "inversion/start_prior.hpp"
#include "inversion/swarm.hpp"
#include "inversion/valley_ladder.hpp"
#include "test_support.hpp"
#include "tipforce/stream_continuity.hpp"

namespace tipforce::inversion {
namespace {

// ---- the swarm --------------------------------------------------------------------------------

// A Rastrigin-like landscape on [0, 1]^2: a bowl around c with a ripple of period 0.2, so local
// minima every 0.2 with values 1-2 above the global one, f(c) = 0.
class RippledBowl : public BatchCost {
 public:
  static constexpr double c[2] = {0.73, 0.21};
  std::vector<double> costs(std::span<const Point> points) override {
    ++batches;
    std::vector<double> out;
    for (const Point& p : points) {
      double f = 0;
      for (int j = 0; j < 2; ++j) {
        const double d = p.x[j] - c[j];
        f += 25 * d * d + 1 - std::cos(2 * std::numbers::pi * 5 * d);
      }
      out.push_back(f);
    }
    return out;
  }
  int batches = 0;
};

TEST(SwarmStage, FindsTheGlobalMinimumOfARippledBowlFromAColdStart) {
  InversionOptions opt;
  SwarmSeeding seeding;
  seeding.particles = opt.swarm_size;
  seeding.generations = opt.max_generations;
  int found = 0;
  for (std::uint64_t seed = 1; seed <= 20; ++seed) {
    RippledBowl f;
    std::mt19937_64 rng(seed);
    Incumbent best;
    const SwarmOutcome out = run_swarm(f, 2, seeding, opt, rng, best);
    EXPECT_EQ(out.generations, f.batches) << "one batch per generation";
    EXPECT_LE(out.generations, seeding.generations);
    EXPECT_FALSE(out.cut_short);
    const bool global = std::abs(best.point.x[0] - RippledBowl::c[0]) < 0.02 && std::abs(best.point.x[1] - RippledBowl::c[1]) < 0.02;
    found += global;
    EXPECT_LT(best.cost, 0.05) << "seed " << seed << ": at " << best.point.x[0] << ", " << best.point.x[1];
  }
  EXPECT_EQ(found, 20) << "the global basin (the nearest local minimum is 1 above it)";
}

TEST(SwarmStage, AWarmSwarmSeededInALocalMinimumStillFindsTheGlobalOne) {
  InversionOptions opt;
  SwarmSeeding seeding;
  seeding.particles = opt.warm_swarm_size;
  seeding.generations = 30;
  seeding.centre = {0.53, 0.21};  // one ripple (0.2) off in x: a local minimum 1 above the global
  seeding.spread = {0.25, 0.25};
  RippledBowl f;
  std::mt19937_64 rng(3);
  Incumbent best;
  run_swarm(f, 2, seeding, opt, rng, best);
  EXPECT_NEAR(best.point.x[0], RippledBowl::c[0], 0.02);
  EXPECT_NEAR(best.point.x[1], RippledBowl::c[1], 0.02);
}

// A flat landscape gains nothing: the swarm stops after stall_generations, and an incumbent
// that no particle beats is kept.
TEST(SwarmStage, StopsWhenNothingImprovesAndKeepsABetterIncumbent) {
  class Flat : public BatchCost {
   public:
    std::vector<double> costs(std::span<const Point> points) override { return std::vector<double>(points.size(), 1.0); }
  } f;
  InversionOptions opt;
  SwarmSeeding seeding;
  seeding.particles = 8;
  seeding.generations = 100;
  std::mt19937_64 rng(1);
  Incumbent best;
  best.point.x = {0.5, 0.5};
  best.cost = 0.5;
  const SwarmOutcome out = run_swarm(f, 2, seeding, opt, rng, best);
  EXPECT_EQ(out.generations, 1 + opt.stall_generations);
  EXPECT_EQ(best.cost, 0.5);
  EXPECT_EQ(best.point.x, (std::vector<double>{0.5, 0.5}));
}

TEST(SwarmStage, APassedDeadlineStopsItBeforeItsFirstBatch) {
  RippledBowl f;
  InversionOptions opt;
  SwarmSeeding seeding;
  seeding.particles = 16;
  seeding.generations = 50;
  std::mt19937_64 rng(1);
  Incumbent best;
  const SwarmOutcome out = run_swarm(f, 2, seeding, opt, rng, best, Deadline(std::chrono::steady_clock::now()));
  EXPECT_TRUE(out.cut_short);
  EXPECT_EQ(out.generations, 0);
  EXPECT_EQ(f.batches, 0);
}

// ---- the polish -------------------------------------------------------------------------------

// y = a exp(-b t) + c on t in [0, 5], with a = v0, b = 3 v1, c = v2 (v in [0, 1]^3), and an
// optional linear part appended (packed coordinates beyond the first three, unbounded).
class ExponentialFit : public LeastSquaresProblem {
 public:
  explicit ExponentialFit(const Eigen::Vector3d& truth) : t_(Eigen::VectorXd::LinSpaced(200, 0.0, 5.0)) {
    y_ = model(truth);
  }
  Eigen::VectorXd model(const Eigen::Vector3d& v) const {
    return (v(0) * (-3 * v(1) * t_.array()).exp() + v(2)).matrix();
  }
  int n_residuals() const override { return static_cast<int>(t_.size()); }
  int n_packed() const override { return 3; }
  int n_unknowns() const override { return 3; }
  Eigen::VectorXd project(const Eigen::VectorXd& v) const override { return v.cwiseMax(0.0).cwiseMin(1.0); }
  double linearise(const Eigen::VectorXd& v, Linearisation& lin) override {
    ++linearisations;
    const Eigen::ArrayXd e = (-3 * v(1) * t_.array()).exp();
    lin.r = y_ - model(v.head<3>());
    lin.J.resize(n_residuals(), 3);
    lin.J.col(0) = e.matrix();
    lin.J.col(1) = (-3 * v(0) * t_.array() * e).matrix();
    lin.J.col(2).setOnes();
    return lin.r.squaredNorm();
  }
  int linearisations = 0;

 private:
  Eigen::VectorXd t_, y_;
};

TEST(PolishStage, ConvergesToTheKnownSolutionOfANonlinearFit) {
  const Eigen::Vector3d truth(0.7, 0.4, 0.15);
  ExponentialFit problem(truth);
  InversionOptions opt;
  Linearisation lin;
  PolishSettings settings;
  settings.max_iterations = 100;
  const PolishResult r =
      LevenbergMarquardt(opt).minimise(problem, StartPrior(3), Eigen::Vector3d(0.3, 0.8, 0.5), settings, lin);
  EXPECT_LT((r.v - truth).cwiseAbs().maxCoeff(), 1e-6) << r.v.transpose();
  EXPECT_LT(r.data_cost, 1e-12);
  EXPECT_GT(r.iterations, 0);
  EXPECT_LE(r.iterations, settings.max_iterations);
  EXPECT_FALSE(r.cut_short);
  // One linearisation at the start, then one per trial point (an accepted step needs no other).
  EXPECT_GE(problem.linearisations, 1 + r.iterations);
}

// Rosenbrock's valley as least squares, r = (10 (x2 - x1^2), 1 - x1) with x = 4 v - 2 (v in the unit
// box), from his classic start x = (-1.2, 1): the minimum is x = (1, 1), v = (0.75, 0.75), at the
// end of a narrow curved valley that plain Levenberg-Marquardt steps zig-zag down.
class RosenbrockValley : public LeastSquaresProblem {
 public:
  int n_residuals() const override { return 2; }
  int n_packed() const override { return 2; }
  int n_unknowns() const override { return 2; }
  Eigen::VectorXd project(const Eigen::VectorXd& v) const override { return v.cwiseMax(0.0).cwiseMin(1.0); }
  static Eigen::Vector2d model(const Eigen::VectorXd& v) {
    const double x1 = 4 * v(0) - 2, x2 = 4 * v(1) - 2;
    return Eigen::Vector2d(-10 * (x2 - x1 * x1), x1);  // data (0, 1) - model = r
  }
  Eigen::VectorXd model_difference(const Eigen::VectorXd& v, const Eigen::VectorXd& probe) override {
    ++residuals;
    return model(probe) - model(v);
  }
  double linearise(const Eigen::VectorXd& v, Linearisation& lin) override {
    ++linearisations;
    const double x1 = 4 * v(0) - 2;
    lin.r = Eigen::Vector2d(0.0, 1.0) - model(v);
    lin.J.resize(2, 2);
    lin.J << 80 * x1, -40, 4, 0;  // d model / dv
    return lin.r.squaredNorm();
  }
  int linearisations = 0, residuals = 0;
};

TEST(PolishStage, GeodesicAccelerationGoesDownACurvedValleyInFewerSteps) {
  InversionOptions opt;
  opt.lm_rel_cost_tolerance = 1e-14;
  opt.lm_step_tolerance = 1e-12;
  int iterations[2] = {0, 0};
  for (bool geodesic : {false, true}) {
    RosenbrockValley problem;
    Linearisation lin;
    PolishSettings settings;
    settings.max_iterations = 500;
    settings.geodesic = geodesic;
    const PolishResult r =
        LevenbergMarquardt(opt).minimise(problem, StartPrior(2), Eigen::Vector2d(0.2, 0.75), settings, lin);
    EXPECT_NEAR(r.v(0), 0.75, 1e-5) << (geodesic ? "geodesic" : "plain");
    EXPECT_NEAR(r.v(1), 0.75, 1e-5) << (geodesic ? "geodesic" : "plain");
    EXPECT_EQ(problem.residuals > 0, geodesic);
    iterations[geodesic] = r.iterations;
    std::printf("%s: %d iterations, %d linearisations, %d residuals\n", geodesic ? "geodesic" : "plain", r.iterations,
                problem.linearisations, problem.residuals);
  }
  EXPECT_LT(iterations[1], iterations[0]);
}

TEST(PolishStage, StaysInsideTheBoundsAtASolutionBeyondThem) {
  // The unconstrained optimum has c = 1.3 > 1: the answer sits on the bound c = 1.
  const Eigen::Vector3d truth(0.7, 0.4, 1.3);
  ExponentialFit problem(truth);
  InversionOptions opt;
  Linearisation lin;
  PolishSettings settings;
  settings.max_iterations = 100;
  const PolishResult r =
      LevenbergMarquardt(opt).minimise(problem, StartPrior(3), Eigen::Vector3d(0.5, 0.5, 0.5), settings, lin);
  EXPECT_DOUBLE_EQ(r.v(2), 1.0);
  EXPECT_TRUE((r.v.array() >= 0).all() && (r.v.array() <= 1).all());
}

// A linear model with a Gaussian prior on its last two coordinates (a "start block"): the answer
// is the closed-form maximum a posteriori, (J'J + H)^-1 J'y with H the prior's Hessian.
class LinearWithPrior : public LeastSquaresProblem {
 public:
  LinearWithPrior(Eigen::MatrixXd J, Eigen::VectorXd y, int m) : J_(std::move(J)), y_(std::move(y)), m_(m) {}
  int n_residuals() const override { return static_cast<int>(J_.rows()); }
  int n_packed() const override { return static_cast<int>(J_.cols()); }
  int n_unknowns() const override { return m_; }
  Eigen::VectorXd project(const Eigen::VectorXd& v) const override {
    Eigen::VectorXd p = v;
    p.head(m_) = p.head(m_).cwiseMax(0.0).cwiseMin(1.0);
    return p;
  }
  double linearise(const Eigen::VectorXd& v, Linearisation& lin) override {
    ++linearisations;
    lin.r = y_ - J_ * v;
    lin.J = J_;
    return lin.r.squaredNorm();
  }
  int linearisations = 0;

 private:
  Eigen::MatrixXd J_;
  Eigen::VectorXd y_;
  int m_;
};

// Data of a linear model, two parameters and a start block of two: a random J, y = J v_true plus
// white noise of sigma.
struct NoisyLinearData {
  static constexpr int N = 300, m = 2, nb = 2;
  static constexpr double sigma = 0.5;
  Eigen::MatrixXd J;
  Eigen::VectorXd y;
  NoisyLinearData() : J(N, m + nb) {
    std::mt19937_64 rng(5);
    std::normal_distribution<double> g(0.0, 1.0);
    for (int i = 0; i < N; ++i)
      for (int j = 0; j < m + nb; ++j) J(i, j) = g(rng);
    y = J * Eigen::Vector4d(0.4, 0.6, 0.3, -0.2);
    for (int i = 0; i < N; ++i) y(i) += sigma * g(rng);
  }
};

TEST(PolishStage, WithAStartPriorGivesTheClosedFormPosteriorMode) {
  const NoisyLinearData d;
  const int m = d.m, nb = d.nb;
  const double sigma = d.sigma;
  const Eigen::MatrixXd& J = d.J;
  const Eigen::VectorXd& y = d.y;
  Eigen::Matrix2d info;
  info << 400.0, 50.0, 50.0, 200.0;
  const StartPrior prior(info, sigma * sigma, m + nb);
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m + nb, m + nb);
  H.bottomRightCorner(nb, nb) = sigma * sigma * info;
  const Eigen::VectorXd map = (J.transpose() * J + H).ldlt().solve(J.transpose() * y);
  ASSERT_TRUE((map.head(m).array() > 0).all() && (map.head(m).array() < 1).all());
  LinearWithPrior problem(J, y, m);
  InversionOptions opt;
  Linearisation lin;
  PolishSettings settings;
  settings.max_iterations = 50;
  settings.noise_var_m2 = sigma * sigma;
  const PolishResult r = LevenbergMarquardt(opt).minimise(problem, prior, Eigen::Vector4d(0.5, 0.5, 0, 0), settings, lin);
  // Converged in chi-square (lm_chi2_tolerance 0.01): within a tenth of a posterior sigma.
  const Eigen::MatrixXd cov = sigma * sigma * (J.transpose() * J + H).inverse();
  for (int j = 0; j < m + nb; ++j) EXPECT_NEAR(r.v(j), map(j), 0.1 * std::sqrt(cov(j, j))) << "coordinate " << j;
}

// ... and with the parameters pooled (StartPrior::with_parameters): a prior centred off the origin
// on the parameters, correlated with the start, whose mode the polish must find as well.
TEST(PolishStage, WithAPooledPriorGivesTheClosedFormPosteriorMode) {
  const NoisyLinearData d;
  const int m = d.m, nb = d.nb, np = m + nb;
  const double var = d.sigma * d.sigma;
  Eigen::Matrix2d start_info;
  start_info << 400.0, 50.0, 50.0, 200.0;
  // The parameters' information given the start: H' R^-1 H with H = [I, -B].
  Eigen::MatrixXd H(m, np);
  H << 1.0, 0.0, -0.3, 0.1, 0.0, 1.0, 0.2, 0.0;
  Eigen::Matrix2d R;
  R << 2e-4, 5e-5, 5e-5, 1e-4;  // sharper than the data (their sigma ~0.03)
  const Eigen::MatrixXd param_info = H.transpose() * R.inverse() * H;
  const Eigen::Vector2d centre(0.3, 0.7);
  const StartPrior prior = StartPrior(start_info, var, np).with_parameters(param_info, centre);
  Eigen::MatrixXd info = param_info;
  info.bottomRightCorner(nb, nb) += start_info;
  Eigen::VectorXd mu = Eigen::VectorXd::Zero(np);
  mu.head(m) = centre;
  const Eigen::MatrixXd A = d.J.transpose() * d.J + var * info;
  const Eigen::VectorXd map = A.ldlt().solve(d.J.transpose() * d.y + var * info * mu);
  ASSERT_TRUE((map.head(m).array() > 0).all() && (map.head(m).array() < 1).all());
  LinearWithPrior problem(d.J, d.y, m);
  Linearisation lin;
  PolishSettings settings;
  settings.max_iterations = 50;
  settings.noise_var_m2 = var;
  const PolishResult r =
      LevenbergMarquardt(InversionOptions{}).minimise(problem, prior, Eigen::Vector4d(0.5, 0.5, 0, 0), settings, lin);
  const Eigen::MatrixXd cov = var * A.inverse();
  for (int j = 0; j < np; ++j) EXPECT_NEAR(r.v(j), map(j), 0.1 * std::sqrt(cov(j, j))) << "coordinate " << j;
  // The mode differs from the start prior's alone by many posterior sigmas: the test can fail.
  const Eigen::MatrixXd A_start = d.J.transpose() * d.J + var * prior.packed_information() - var * param_info;
  const Eigen::VectorXd start_only = A_start.ldlt().solve(d.J.transpose() * d.y);
  EXPECT_GT(std::abs(start_only(0) - map(0)), 3 * std::sqrt(cov(0, 0)));
}

// Nearly undamped, the first step of a linear model is the exact Gauss-Newton step, and the polish
// knows it has arrived from that point's own linearisation (the chi-square a further step would
// gain): one iteration and two linearisations, not a second step that gains nothing.
TEST(PolishStage, RecognisesTheMinimumFromItsOwnLinearisation) {
  const NoisyLinearData d;
  const int m = d.m, nb = d.nb;
  const double sigma = d.sigma;
  const Eigen::MatrixXd& J = d.J;
  const Eigen::VectorXd& y = d.y;
  const Eigen::VectorXd ls = (J.transpose() * J).ldlt().solve(J.transpose() * y);
  ASSERT_TRUE((ls.head(m).array() > 0).all() && (ls.head(m).array() < 1).all());
  LinearWithPrior problem(J, y, m);
  InversionOptions opt;
  Linearisation lin;
  PolishSettings settings;
  settings.max_iterations = 50;
  settings.noise_var_m2 = sigma * sigma;
  settings.initial_lambda = 1e-12;
  const PolishResult r =
      LevenbergMarquardt(opt).minimise(problem, StartPrior(m + nb), Eigen::Vector4d(0.5, 0.5, 0, 0), settings, lin);
  EXPECT_EQ(r.iterations, 1);
  EXPECT_EQ(problem.linearisations, 2);
  const Eigen::MatrixXd cov = sigma * sigma * (J.transpose() * J).inverse();
  for (int j = 0; j < m + nb; ++j) EXPECT_NEAR(r.v(j), ls(j), 1e-3 * std::sqrt(cov(j, j))) << "coordinate " << j;
}

// A tracking polish that could not reach its limit gives up before its first step when the start's
// own linearisation predicts so: a linear model's Gauss-Newton prediction is exact, so the test
// is against the least-squares minimum's cost, and progress the step would make keeps it going.
TEST(PolishStage, GivesUpBeforeItsFirstStepWhenTheStepCannotReachTheLimit) {
  const NoisyLinearData d;
  const Eigen::VectorXd ls = (d.J.transpose() * d.J).ldlt().solve(d.J.transpose() * d.y);
  const double min_cost = (d.y - d.J * ls).squaredNorm();
  const Eigen::Vector4d start(0.9, 0.1, 0, 0);
  const double start_cost = (d.y - d.J * start).squaredNorm();
  ASSERT_GT(start_cost, 3 * min_cost);
  struct Case {
    const char* what;
    double limit, progress;
    bool gives_up;
  };
  for (const Case c : {Case{"the minimum above the limit", 0.9 * min_cost, 0.0, true},
                       Case{"the minimum within the limit", 1.1 * min_cost, 0.0, false},
                       Case{"the step keeps less than the progress fraction", 0.9 * min_cost,
                            1.1 * min_cost / start_cost, false}}) {
    LinearWithPrior problem(d.J, d.y, d.m);
    InversionOptions opt;
    Linearisation lin;
    PolishSettings settings;
    settings.max_iterations = 50;
    settings.noise_var_m2 = d.sigma * d.sigma;
    settings.initial_lambda = 1e-12;
    settings.give_up_after = 1;
    settings.give_up_data_cost = c.limit;
    settings.give_up_progress = c.progress;
    settings.give_up_predicted = true;
    const PolishResult r = LevenbergMarquardt(opt).minimise(problem, StartPrior(d.m + d.nb), start, settings, lin);
    EXPECT_EQ(r.gave_up, c.gives_up) << c.what;
    if (c.gives_up) {
      EXPECT_EQ(r.iterations, 0) << c.what;
      EXPECT_EQ(problem.linearisations, 1) << c.what;
      EXPECT_DOUBLE_EQ(r.data_cost, start_cost) << c.what;
    } else {
      EXPECT_NEAR(r.data_cost, min_cost, 1e-9 * min_cost) << c.what;
    }
  }
}

// r = -atan(20 (v - 0.3)) - wall (v - 0.3)^2 below 0.3, v in [0, 1], from v = 0.6: the
// Gauss-Newton step (-2.6) overshoots into the bound at 0. Without the wall the cost there equals
// the start's: the parabola through the start's cost and slope and the trial's cost has its
// minimum half way along the step (Moré's rule: at the truth), so one rejected trial is enough; a
// fixed factor of 8 on lambda needs four (lambda 1e-3 -> 4). With a wall the trial costs more
// than the start, and the parabola's minimum lies inside (0.1, 0.5) of the step.
class OvershootingArctan : public LeastSquaresProblem {
 public:
  explicit OvershootingArctan(double wall = 0) : wall_(wall) {}
  int n_residuals() const override { return 1; }
  int n_packed() const override { return 1; }
  int n_unknowns() const override { return 1; }
  Eigen::VectorXd project(const Eigen::VectorXd& v) const override { return v.cwiseMax(0.0).cwiseMin(1.0); }
  double model(double v) const { return std::atan(20 * (v - 0.3)) + (v < 0.3 ? wall_ * (v - 0.3) * (v - 0.3) : 0.0); }
  double slope(double v) const { return 20 / (1 + 400 * (v - 0.3) * (v - 0.3)) + (v < 0.3 ? 2 * wall_ * (v - 0.3) : 0.0); }
  double linearise(const Eigen::VectorXd& v, Linearisation& lin) override {
    ++linearisations;
    lin.r = Eigen::VectorXd::Constant(1, -model(v(0)));
    lin.J = Eigen::MatrixXd::Constant(1, 1, slope(v(0)));
    return lin.r.squaredNorm();
  }
  int linearisations = 0;

 private:
  double wall_;
};

TEST(PolishStage, ARejectedStepIsShortenedToWhereTheCostAlongItTurns) {
  int first_step_linearisations[2] = {0, 0};
  for (bool interpolate : {false, true}) {
    InversionOptions opt;
    opt.lm_interpolate_rejected = interpolate;
    Linearisation lin;
    PolishSettings settings;
    settings.max_iterations = 1;
    OvershootingArctan first;
    const PolishResult one =
        LevenbergMarquardt(opt).minimise(first, StartPrior(1), Eigen::VectorXd::Constant(1, 0.6), settings, lin);
    ASSERT_EQ(one.iterations, 1);
    first_step_linearisations[interpolate] = first.linearisations;
    if (interpolate) {
      EXPECT_NEAR(one.v(0), 0.3, 0.01 * 0.3);  // half the step, to the damping search's 1 %
    }
    settings.max_iterations = 50;
    OvershootingArctan all;
    const PolishResult r =
        LevenbergMarquardt(opt).minimise(all, StartPrior(1), Eigen::VectorXd::Constant(1, 0.6), settings, lin);
    EXPECT_NEAR(r.v(0), 0.3, 1e-6) << (interpolate ? "interpolated" : "fixed factor");
  }
  EXPECT_EQ(first_step_linearisations[1], 3);  // the start, the rejected trial, the accepted one
  EXPECT_EQ(first_step_linearisations[0], 6);  // the start, four rejected trials, the accepted one
}

// With the wall: t = -s / (2 (c1 - c0 - s)) with s = -2 g step, worked out here from the model,
// and the accepted step is t of the rejected one.
TEST(PolishStage, ARejectedStepIsShortenedToTheParabolasMinimumInsideTheStep) {
  OvershootingArctan problem(36.0);
  const double v0 = 0.6, r0 = -problem.model(v0), g = problem.slope(v0) * r0;
  const double c0 = r0 * r0, c1 = problem.model(0.0) * problem.model(0.0);  // the trial at the bound
  const double step = 0.0 - v0, s = -2 * g * step;
  const double t = -s / (2 * (c1 - c0 - s));
  ASSERT_GT(t, 0.15);
  ASSERT_LT(t, 0.45);
  InversionOptions opt;
  Linearisation lin;
  PolishSettings settings;
  settings.max_iterations = 1;
  const PolishResult one = LevenbergMarquardt(opt).minimise(problem, StartPrior(1), Eigen::VectorXd::Constant(1, v0), settings, lin);
  ASSERT_EQ(one.iterations, 1);
  EXPECT_NEAR(v0 - one.v(0), t * std::abs(step), 0.01 * t * std::abs(step)) << "t " << t;
}

TEST(PolishStage, APassedDeadlineStopsItAtItsStart) {
  ExponentialFit problem(Eigen::Vector3d(0.7, 0.4, 0.15));
  InversionOptions opt;
  Linearisation lin;
  const Eigen::Vector3d start(0.3, 0.8, 0.5);
  const PolishResult r = LevenbergMarquardt(opt).minimise(problem, StartPrior(3), start, PolishSettings{}, lin,
                                                          Deadline(std::chrono::steady_clock::now()));
  EXPECT_TRUE(r.cut_short);
  EXPECT_EQ(r.iterations, 0);
  EXPECT_EQ(r.v, Eigen::VectorXd(start));
  EXPECT_EQ(problem.linearisations, 1) << "the start's linearisation, for its covariance";
}

// ---- the valley's rungs ----------------------------------------------------------------------

TEST(ValleyStage, TheParabolasVertexIsAQuadraticsMinimumAndStaysBetweenItsNeighbours) {
  auto q = [](double x) { return 3.0 * (x - 0.37) * (x - 0.37) + 1.0; };
  EXPECT_NEAR(parabola_vertex(0.0, q(0.0), 0.5, q(0.5), 1.5, q(1.5)), 0.37, 1e-12);  // uneven spacing
  EXPECT_NEAR(parabola_vertex(-1.0, q(-1.0), 0.2, q(0.2), 0.3, q(0.3)), 0.3, 1e-12);  // beyond: clamped
  EXPECT_EQ(parabola_vertex(0.0, 2.0, 1.0, 2.0, 2.0, 2.0), 1.0);                      // flat
  EXPECT_EQ(parabola_vertex(0.0, 1.0, 1.0, 2.0, 2.0, 1.0), 1.0);                      // bending down
}

// Costs quadratic in log factor about (f0, g0): the grid's refinement lands on them where they lie
// between rungs, and looks one rung (stiffness) or one and two (force) beyond the grid's end.
TEST(ValleyStage, TheRefinementFindsTheMinimumBetweenRungsAndLooksBeyondTheGridsEnd) {
  const std::vector<double> f = {0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0}, g = {0.7, 1.0, 1.4};
  const std::vector<int> unknowns = {0, 2};
  const std::vector<ValleyRung> grid = valley_grid(unknowns, f, g);
  ASSERT_EQ(grid.size(), 2 * f.size() * g.size() - g.size());  // the unscaled rungs once
  auto costs_about = [&](double f0, double g0) {
    std::vector<double> c;
    for (const ValleyRung& r : grid) {
      const double a = std::log(r.stiffness_factor / f0), b = std::log(r.force_factor / g0);
      c.push_back(1.0 + a * a + 0.5 * b * b + (r.unknown == 0 ? 0.0 : 0.3));
    }
    return c;
  };
  {  // between rungs: the two vertices, and both together
    const std::vector<ValleyRung> r = valley_refinement(grid, costs_about(2.4, 0.85), f, g);
    ASSERT_EQ(r.size(), 3u);
    bool both = false;
    for (const ValleyRung& x : r) {
      EXPECT_EQ(x.unknown, 0);
      both |= std::abs(x.stiffness_factor - 2.4) < 1e-9 && std::abs(x.force_factor - 0.85) < 1e-9;
    }
    EXPECT_TRUE(both);
  }
  {  // beyond both ends: the stiffness one rung further at the best force, the force one and two
    const std::vector<ValleyRung> r = valley_refinement(grid, costs_about(6.0, 3.0), f, g);
    ASSERT_EQ(r.size(), 3u);
    EXPECT_NEAR(r[0].stiffness_factor, 4.0 * 4.0 / 2.8, 1e-12);
    EXPECT_EQ(r[0].force_factor, 1.4);
    EXPECT_EQ(r[1].stiffness_factor, 4.0);
    EXPECT_NEAR(r[1].force_factor, 1.4 * 1.4, 1e-12);
    EXPECT_NEAR(r[2].force_factor, 1.4 * 1.4 * 1.4, 1e-12);
  }
  {  // the stiffness beyond its end at the best force, the force's vertex at the best stiffness,
     // and no combination of the two (only vertices are combined)
    const std::vector<ValleyRung> r = valley_refinement(grid, costs_about(6.0, 0.85), f, g);
    ASSERT_EQ(r.size(), 2u);
    EXPECT_NEAR(r[0].stiffness_factor, 4.0 * 4.0 / 2.8, 1e-12);
    EXPECT_EQ(r[0].force_factor, 1.0);
    EXPECT_EQ(r[1].stiffness_factor, 4.0);
    EXPECT_NEAR(r[1].force_factor, 0.85, 1e-9);
  }
  {  // no finite cost: nothing
    const std::vector<double> none(grid.size(), std::numeric_limits<double>::infinity());
    EXPECT_TRUE(valley_refinement(grid, none, f, g).empty());
  }
}

// ---- the covariance ---------------------------------------------------------------------------

// White noise: the estimated covariance of a linear least-squares fit is sigma^2 (J'J)^-1 (the
// bounds' information, 12 per normalised unknown, is negligible beside the data's here), the
// start block marginalised by taking the unknowns' block; and over many noise draws the estimates
// scatter as the sigmas say.
TEST(CovarianceStage, MatchesTheClosedFormOfALinearGaussianModelAndTheEstimatesScatter) {
  std::mt19937_64 rng(9);
  std::normal_distribution<double> g(0.0, 1.0);
  const int N = 2000, m = 2, nb = 2, np = m + nb;
  const double sigma = 0.01;
  Eigen::MatrixXd J(N, np);
  for (int i = 0; i < N; ++i) {
    const double t = i / double(N);
    J.row(i) << std::sin(7 * t), t, std::cos(3 * t), 1.0;  // correlated columns
  }
  const Eigen::MatrixXd closed = sigma * sigma * (J.transpose() * J).inverse();
  const std::vector<double> widths = {2.0, 0.5};
  const std::vector<std::string> names = {"a", "b"};
  const Eigen::VectorXd v_true = (Eigen::VectorXd(np) << 0.4, 0.7, 0.1, -0.3).finished();
  std::vector<std::vector<double>> estimates(m);
  double mean_rel_sigma_error[m] = {0, 0};
  const int draws = 400;
  for (int d = 0; d < draws; ++d) {
    Eigen::VectorXd y = J * v_true;
    for (int i = 0; i < N; ++i) y(i) += sigma * g(rng);
    const Eigen::VectorXd v = (J.transpose() * J).ldlt().solve(J.transpose() * y);
    const Eigen::VectorXd r = y - J * v;
    const Uncertainty u = posterior_uncertainty(J, r, r.squaredNorm(), Eigen::MatrixXd(), widths, names,
                                                {v(0), v(1)}, InversionOptions{});
    ASSERT_TRUE(u.identifiable);
    for (int j = 0; j < m; ++j) {
      const double expected = widths[j] * std::sqrt(closed(j, j));
      mean_rel_sigma_error[j] += (u.sigma[j] / expected - 1) / draws;
      estimates[j].push_back(v(j));
      EXPECT_TRUE(u.determined[j]);
    }
    if (d == 0) {
      const double corr = closed(0, 1) / std::sqrt(closed(0, 0) * closed(1, 1));
      EXPECT_NEAR(u.covariance(0, 1) / std::sqrt(u.covariance(0, 0) * u.covariance(1, 1)), corr, 0.02);
      EXPECT_EQ(u.full_covariance.rows(), np);
    }
  }
  for (int j = 0; j < m; ++j) {
    // The residual variance is estimated (scatter sqrt(2 / N) ~ 3 % per draw) and the HAC factor
    // is at least 1: on average within 2 %.
    EXPECT_NEAR(mean_rel_sigma_error[j], 0.0, 0.02) << names[j];
    double mean = 0, var = 0;
    for (double e : estimates[j]) mean += e / draws;
    for (double e : estimates[j]) var += (e - mean) * (e - mean) / (draws - 1);
    // The normalised estimates' scatter against sqrt(closed): within 10 % (400 draws: ~3.5 %).
    EXPECT_NEAR(std::sqrt(var) / std::sqrt(closed(j, j)), 1.0, 0.1) << names[j];
  }
}

// An unknown the data do not determine at all: its sigma is the bounds' own spread (width /
// sqrt(12)), it is marked undetermined, and no singular matrix is reported for it.
TEST(CovarianceStage, AnUnknownTheDataIgnoreGetsTheSpreadOfItsBounds) {
  const int N = 500;
  Eigen::MatrixXd J(N, 2);
  std::mt19937_64 rng(2);
  std::normal_distribution<double> g(0.0, 1e-3);
  Eigen::VectorXd r(N);
  for (int i = 0; i < N; ++i) {
    J(i, 0) = std::sin(0.1 * i);
    J(i, 1) = 1e-12 * std::cos(0.1 * i);  // moves the signal by nothing measurable
    r(i) = g(rng);
  }
  const Uncertainty u = posterior_uncertainty(J, r, r.squaredNorm(), Eigen::MatrixXd(), {1.0, 6.0}, {"a", "b"},
                                              {0.5, 0.5}, InversionOptions{});
  EXPECT_TRUE(u.determined[0]);
  EXPECT_FALSE(u.determined[1]);
  EXPECT_NEAR(u.sigma[1], 6.0 / std::sqrt(12.0), 1e-6);
  EXPECT_NE(u.notes.find("b barely determined"), std::string::npos) << u.notes;
}

// AR(1) residuals r_n = phi r_(n-1) + e_n: the variance of a mean is inflated by the long-run
// factor (1 + phi) / (1 - phi) over white noise. The Bartlett estimate over L lags approaches it
// less 2 phi / ((L + 1)(1 - phi)^2); white noise gives 1, and anticorrelated residuals (a factor
// below 1) are not allowed to shrink the uncertainty.
TEST(CovarianceStage, HacFactorOfAr1ResidualsIsTheirLongRunVarianceRatio) {
  const int N = 200000, lags = 200;
  for (double phi : {0.0, 0.5, 0.8, -0.5}) {
    std::mt19937_64 rng(17);
    std::normal_distribution<double> g(0.0, 1.0);
    Eigen::VectorXd r(N);
    double prev = 0;
    for (int n = 0; n < N; ++n) prev = r(n) = phi * prev + g(rng);
    const double long_run = (1 + phi) / (1 - phi);
    const double bartlett = long_run - 2 * phi / ((lags + 1) * (1 - phi) * (1 - phi));
    const double expected = std::max(1.0, bartlett);
    EXPECT_NEAR(hac_inflation(r, lags), expected, 0.05 * expected) << "phi " << phi;
  }
}

// The factor from its definition, written out plainly (1 + 2 sum over k of the Bartlett weight
// times the lag-k autocorrelation, at least 1), to rounding, on short residuals whose lag sums run
// into the window's end or past it (the AR(1) test above holds only to 5 % and would miss an edge term).
TEST(CovarianceStage, HacFactorIsItsDefinitionAtEveryLagCountAndWindowEnd) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int N : {2, 9, 17, 40, 333})
    for (int lags : {1, 7, 8, 9, 15, 16, 17, 39}) {  // some beyond the window's end: terms of zero
      Eigen::VectorXd r(N);
      double prev = 0;
      for (int n = 0; n < N; ++n) prev = r(n) = 0.7 * prev + g(rng);
      double r0 = 0, tau = 1;
      for (int n = 0; n < N; ++n) r0 += r(n) * r(n);
      for (int k = 1; k <= lags; ++k) {
        double sum = 0;
        for (int n = 0; n + k < N; ++n) sum += r(n) * r(n + k);
        tau += 2.0 * (1.0 - static_cast<double>(k) / (lags + 1)) * sum / r0;
      }
      EXPECT_NEAR(hac_inflation(r, lags), std::max(1.0, tau), 1e-12 * std::max(1.0, tau)) << N << " samples, " << lags << " lags";
    }
}

// The lag products are built for three instruction sets and chosen at run time (cpu_step.hpp): the
// build this CPU runs against the baseline's and against the plain sums, at a 1 MHz window's size
// and at edges of the blocks of 32 lags.
TEST(CovarianceStage, LagProductsOfTheDispatchedBuildAreTheBaselines) {
  std::mt19937_64 rng(11);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int N : {5, 33, 64, 1250})
    for (int lags : {1, 4, 31, 32, 33, 63, 64, 65, 200}) {
      if (lags >= N) continue;
      std::vector<double> r(static_cast<std::size_t>(N));
      for (double& x : r) x = g(rng);
      std::vector<double> best(static_cast<std::size_t>(lags)), base(best.size());
      cpu::lag_products(r.data(), N, lags, best.data(), /*best=*/true);
      cpu::lag_products(r.data(), N, lags, base.data(), /*best=*/false);
      for (int k = 1; k <= lags; ++k) {
        double sum = 0, scale = 0;
        for (int n = 0; n + k < N; ++n) {
          sum += r[static_cast<std::size_t>(n)] * r[static_cast<std::size_t>(n + k)];
          scale += std::abs(r[static_cast<std::size_t>(n)] * r[static_cast<std::size_t>(n + k)]);
        }
        const std::size_t i = static_cast<std::size_t>(k - 1);
        EXPECT_NEAR(best[i], base[i], 1e-14 * scale) << N << " samples, lag " << k;
        EXPECT_NEAR(base[i], sum, 1e-14 * scale) << N << " samples, lag " << k;
      }
    }
}

// ---- the start-conflict statistic -------------------------------------------------------------

// In the linear-Gaussian model it is the innovation's chi-square: with the start drawn from its
// prior, chi-square with 4 degrees of freedom (mean 4; beyond 100 essentially never); with the
// start off its prior, noncentral, as the closed form says.
TEST(StartConflictStage, IsChiSquareWithFourDegreesOfFreedomWhenTheStartFollowsItsPrior) {
  std::mt19937_64 rng(23);
  std::normal_distribution<double> g(0.0, 1.0);
  const int N = 400, m = 2, nb = 4, np = m + nb;
  const double sigma = 1.0;
  Eigen::MatrixXd J(N, np);
  for (int i = 0; i < N; ++i)
    for (int j = 0; j < np; ++j) J(i, j) = std::sin(0.05 * (j + 1) * i + j) + 0.1 * g(rng);
  // A prior a few times sharper than the data on the start.
  const Eigen::MatrixXd data_info = J.transpose() * J / (sigma * sigma);
  const Eigen::MatrixXd info = 3.0 * data_info.bottomRightCorner(nb, nb);
  const StartPrior prior(info, sigma * sigma, np);
  const Eigen::MatrixXd prior_cov = info.inverse();
  const Eigen::LLT<Eigen::MatrixXd> prior_chol(prior_cov);
  auto statistic = [&](const Eigen::VectorXd& start_offset) {
    Eigen::VectorXd v_true(np);
    v_true << 0.4, 0.6, start_offset;
    Eigen::VectorXd y = J * v_true;
    for (int i = 0; i < N; ++i) y(i) += sigma * g(rng);
    // The posterior mode, and the linearisation there, as the polish leaves them.
    const Eigen::VectorXd v = (J.transpose() * J + prior.hessian()).ldlt().solve(J.transpose() * y);
    Linearisation lin;
    lin.J = J;
    lin.r = y - J * v;
    return start_conflict_chi2(lin, prior, v, m);
  };
  const int draws = 2000;
  double mean = 0, largest = 0;
  for (int d = 0; d < draws; ++d) {
    Eigen::VectorXd z(nb);
    for (int i = 0; i < nb; ++i) z(i) = g(rng);
    const double c = statistic(prior_chol.matrixL() * z);
    mean += c / draws;
    largest = std::max(largest, c);
  }
  EXPECT_NEAR(mean, 4.0, 0.3) << "chi-square mean: its degrees of freedom";
  EXPECT_LT(largest, 40.0) << "chi-square(4) exceeds 40 with probability 3e-8";
  // A start off its prior by delta: noncentral chi-square, mean 4 + delta' (P + C)^-1 delta, with
  // P the prior's covariance and C the data's own on the start (the parameters marginalised; the
  // statistic counts the bounds' information on them, as here).
  Eigen::MatrixXd A = data_info;
  for (int j = 0; j < m; ++j) A(j, j) += 12.0;
  const Eigen::MatrixXd C = A.inverse().bottomRightCorner(nb, nb);
  Eigen::VectorXd off = Eigen::VectorXd::Zero(nb);
  off(0) = 30 * std::sqrt(prior_cov(0, 0));
  const double lambda = off.dot((prior_cov + C).ldlt().solve(off));
  double far = 0;
  for (int d = 0; d < 200; ++d) far += statistic(off) / 200;
  EXPECT_NEAR(far, 4 + lambda, 0.05 * (4 + lambda)) << "noncentrality " << lambda;
  EXPECT_GT(far, 100.0) << "30 prior sigmas off: above the threshold";
}

// ---- pooling across pixels (parameter_prior.hpp) ------------------------------------------------

// The previous fit's parameters (normalised) and end state (physical units) with a random joint
// covariance, in the coordinates of a continued 5 MHz window of the paper's cantilever.
struct PreviousJointFit {
  ModalModel modal{testing::paper_probe()};
  ParameterSpace space{ForceModelKind::spring};
  std::optional<Coordinates> coordinates;
  PreviousFit previous;
  Eigen::MatrixXd joint_scaled;  // (x, start shifts) in the packed coordinates: what the previous fit knew
  Eigen::VectorXd x;
  std::vector<double> drift{0.05, 0.01};
  Eigen::MatrixXd drift_var;     // m x m, normalised
  static constexpr int m = 2, nb = 4;

  PreviousJointFit() {
    space.make_unknown("k_n_per_m", 0.5, 20.0);
    space.make_unknown("h_m", 10e-9, 70e-9);
    coordinates.emplace(space, modal, 20e-9, true);
    std::mt19937_64 rng(7);
    std::normal_distribution<double> g(0.0, 1.0);
    Eigen::MatrixXd L(m + nb, m + nb);
    for (int i = 0; i < m + nb; ++i)
      for (int j = 0; j < m + nb; ++j) L(i, j) = g(rng);
    // Correlated parameters and start (the stiffer estimate ends elsewhere), 0.01-0.05 sigmas.
    joint_scaled = 1e-3 * (L * L.transpose() + 0.1 * Eigen::MatrixXd::Identity(m + nb, m + nb));
    Eigen::VectorXd scale = Eigen::VectorXd::Ones(m + nb);
    for (int i = 0; i < coordinates->n_start_modes(); ++i) {
      scale(m + 2 * i) = coordinates->q_scale(i);
      scale(m + 2 * i + 1) = coordinates->v_scale(i);
    }
    const Eigen::MatrixXd phys = scale.asDiagonal() * joint_scaled * scale.asDiagonal();
    x = Eigen::Vector2d(0.6, 0.55);
    const Point centre{{x(0), x(1)}};
    previous.values = coordinates->values(centre.x);
    previous.param_cov = phys.topLeftCorner(m, m);
    previous.param_end_cov = phys.topRightCorner(m, nb);
    previous.end_cov = phys.bottomRightCorner(nb, nb);
    drift_var = Eigen::MatrixXd::Zero(m, m);
    for (int j = 0; j < m; ++j)
      drift_var(j, j) = std::pow(drift[static_cast<std::size_t>(j)] * previous.values[static_cast<std::size_t>(j)] / coordinates->width(j), 2);
  }
  // What the previous fit and the drift say of this window's (x, s), directly: the joint
  // Gaussian, the drift on x.
  Eigen::MatrixXd prior_covariance() const {
    Eigen::MatrixXd c = joint_scaled;
    c.topLeftCorner(m, m) += drift_var;
    return c;
  }
  Eigen::MatrixXd start_information() const { return start_prior_information(previous.end_cov, *coordinates, 0.0); }
  // A window's data on (x, s): their information (40 random residuals), and the window's
  // covariance with its start prior (what pooling_step takes as the window's own).
  struct WindowData {
    Eigen::MatrixXd information, own_covariance;
  };
  WindowData window_data(std::uint64_t seed) const {
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> g(0.0, 1.0);
    Eigen::MatrixXd J(40, m + nb);
    for (int i = 0; i < J.rows(); ++i)
      for (int j = 0; j < J.cols(); ++j) J(i, j) = g(rng);
    WindowData d;
    d.information = 30.0 * J.transpose() * J;
    Eigen::MatrixXd with_start = d.information;
    with_start.bottomRightCorner(nb, nb) += start_information();
    d.own_covariance = with_start.inverse();
    return d;
  }
};

// The parameters given the start, with the start's own prior, must be the joint prior: their
// information summed is the inverse of the joint covariance, drift added (computed directly), and
// the Kalman step from a window's own answer lands on the mode of data times joint prior.
TEST(PoolingStage, TheParametersGivenTheStartAndTheStartPriorAreTheJointPrior) {
  const PreviousJointFit f;
  const int m = f.m, nb = f.nb;
  const Eigen::MatrixXd start_info = f.start_information();
  const auto pp = parameter_prior(f.previous, *f.coordinates, start_info, f.drift);
  ASSERT_TRUE(pp.has_value());
  EXPECT_LT((pp->centre - f.x).norm(), 1e-12);
  Eigen::MatrixXd info = pp->packed_information();
  info.bottomRightCorner(nb, nb) += start_info;
  const Eigen::MatrixXd joint_info = f.prior_covariance().inverse();
  EXPECT_LT((info - joint_info).norm(), 1e-8 * joint_info.norm());

  // A window's data: information A_d about (x, s), its own optimum v_d.
  const PreviousJointFit::WindowData data = f.window_data(11);
  const Eigen::MatrixXd& A_d = data.information;
  const Eigen::MatrixXd& C_w = data.own_covariance;
  Eigen::VectorXd v_d(m + nb);
  v_d << f.x(0) + 0.02, f.x(1) - 0.01, 0.1, -0.2, 0.05, 0.0;
  const Eigen::VectorXd v_w = C_w * A_d * v_d;  // the window with its start prior (centred on no shift)
  Eigen::VectorXd mu = Eigen::VectorXd::Zero(m + nb);
  mu.head(m) = f.x;
  const Eigen::VectorXd mode = (A_d + joint_info).ldlt().solve(A_d * v_d + joint_info * mu);
  const PoolingStep step = pooling_step(*pp, v_w, C_w);
  EXPECT_LT((step.v - mode).norm(), 1e-8 * mode.norm());

  // The same prior through StartPrior::with_parameters: its penalty is the joint prior's quadratic
  // form, weighed by the noise variance.
  const double var = 4e-20;
  const StartPrior pooled = StartPrior(start_info, var, m + nb).with_parameters(pp->packed_information(), pp->centre);
  const Eigen::VectorXd d = v_d - mu;
  EXPECT_NEAR(pooled.cost(v_d), var * d.dot(joint_info * d), 1e-9 * var * d.dot(joint_info * d));
  EXPECT_NEAR(pooled.information().norm(), start_info.norm(), 1e-12 * start_info.norm()) << "the start's marginal stays";
}

// Where the sample does not change, the innovation is chi-square with m degrees of freedom: the
// truth drawn from the joint prior, the window's data scattered about it by their own covariance.
// A parameter off by many of the combined sigmas (an edge) exceeds the gate.
TEST(PoolingStage, TheInnovationIsChiSquareWithOneDegreeOfFreedomPerParameter) {
  const PreviousJointFit f;
  const int m = f.m, nb = f.nb;
  const auto pp = parameter_prior(f.previous, *f.coordinates, f.start_information(), f.drift);
  ASSERT_TRUE(pp.has_value());
  const PreviousJointFit::WindowData data = f.window_data(5);
  const Eigen::MatrixXd& A_d = data.information;
  const Eigen::MatrixXd& C_w = data.own_covariance;
  std::mt19937_64 rng(6);
  std::normal_distribution<double> g(0.0, 1.0);
  const Eigen::LLT<Eigen::MatrixXd> prior_chol(f.prior_covariance()), data_chol(A_d.inverse());
  Eigen::VectorXd mu = Eigen::VectorXd::Zero(m + nb);
  mu.head(m) = f.x;
  auto chi2 = [&](const Eigen::VectorXd& shift) {
    Eigen::VectorXd z1(m + nb), z2(m + nb);
    for (int i = 0; i < m + nb; ++i) z1(i) = g(rng), z2(i) = g(rng);
    const Eigen::VectorXd truth = mu + shift + prior_chol.matrixL() * z1;
    const Eigen::VectorXd v_d = truth + data_chol.matrixL() * z2;
    return pooling_step(*pp, C_w * A_d * v_d, C_w).innovation_chi2;
  };
  const int draws = 4000;
  double mean = 0, beyond_gate = 0;
  for (int d = 0; d < draws; ++d) {
    const double c = chi2(Eigen::VectorXd::Zero(m + nb));
    mean += c / draws;
    beyond_gate += c > InversionOptions{}.pool_gate_chi2;
  }
  EXPECT_NEAR(mean, m, 0.15) << "chi-square mean: its degrees of freedom";
  EXPECT_LE(beyond_gate, 10) << "chi-square(2) exceeds 16 with probability 3e-4";
  // k of the sample moved by ten of the prior's and the data's sigmas together: noncentrality
  // about 100 (the start's correlation moves it a little), far beyond the gate.
  Eigen::VectorXd edge = Eigen::VectorXd::Zero(m + nb);
  edge(0) = 10 * std::sqrt(f.prior_covariance()(0, 0) + A_d.inverse()(0, 0));
  double edge_mean = 0;
  for (int d = 0; d < 200; ++d) edge_mean += chi2(edge) / 200;
  EXPECT_GT(edge_mean, 4 * InversionOptions{}.pool_gate_chi2);
}

// For a linear model the innovation measured on the model (pooled_innovation_chi2: the joint
// negative log posterior at the pooled optimum less the window's own, each from its data's sum of
// squares and its prior's penalty) is the Kalman filter's normalised innovation, at an unchanged
// sample and at an edge. Both optima in closed form; data of 40 residuals whose noise variance
// makes their information that of window_data.
TEST(PoolingStage, TheInnovationOnTheModelIsTheKalmanInnovationForALinearModel) {
  const PreviousJointFit f;
  const int m = f.m, nb = f.nb, np = m + nb;
  const Eigen::MatrixXd start_info = f.start_information();
  const auto pp = parameter_prior(f.previous, *f.coordinates, start_info, f.drift);
  ASSERT_TRUE(pp.has_value());
  const double var = 1.0 / 30.0;
  std::mt19937_64 rng(11);
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::MatrixXd J(40, np);
  for (int i = 0; i < J.rows(); ++i)
    for (int j = 0; j < np; ++j) J(i, j) = g(rng);
  const StartPrior own_prior(start_info, var, np);
  const StartPrior pooled = own_prior.with_parameters(pp->packed_information(), pp->centre);
  Eigen::VectorXd mu = Eigen::VectorXd::Zero(np);
  mu.head(m) = pp->centre;
  const Eigen::MatrixXd S = own_prior.packed_information(), P = pooled.packed_information();
  const Eigen::MatrixXd A = J.transpose() * J / var;
  for (const double edge : {0.0, 0.8}) {
    Eigen::VectorXd truth = mu;
    truth(0) += edge;
    Eigen::VectorXd y = J * truth;
    for (int i = 0; i < y.size(); ++i) y(i) += std::sqrt(var) * g(rng);
    const Eigen::MatrixXd own_cov = (A + S).inverse();
    const Eigen::VectorXd own_v = own_cov * J.transpose() * y / var;
    const Eigen::VectorXd pooled_v = (A + P).ldlt().solve(J.transpose() * y / var + P * mu);
    const double on_model = pooled_innovation_chi2((y - J * pooled_v).squaredNorm(), pooled_v, pooled,
                                                   (y - J * own_v).squaredNorm(), own_v, own_prior, var);
    const double kalman = pooling_step(*pp, own_v, own_cov).innovation_chi2;
    EXPECT_NEAR(on_model, kalman, 1e-6 * kalman) << "edge " << edge;
    if (edge > 0) {
      EXPECT_GT(kalman, 4 * InversionOptions{}.pool_gate_chi2) << "the edge must count";
    }
  }
}

// ---- the start estimate -----------------------------------------------------------------------

// A free oscillation (no surface) from a known state: the drive's steady state with mode 1 moved
// off it, simulated by the reference integrator. The estimate must recover mode 1's displacement
// and velocity at the first sample from the first eighth of its period. A quadratic fitted there
// misses the cubic term of the oscillation: about (omega T)^3 / 120 = 0.4 % of the amplitude in
// displacement and (omega T)^2 / 10 = 6 % of omega x amplitude in velocity, with T the fitted
// span (an eighth of a period); the other modes sit in their steady state, which is subtracted.
TEST(StartEstimateStage, RecoversTheStateOfAFreeOscillationFromItsFirstSamples) {
  const ModalModel modal(testing::paper_probe());
  const double f1 = modal.modes()[0].frequency_hz, omega1 = modal.modes()[0].omega_rad_per_s;
  const InversionOptions opt;
  for (double dt : {1e-7, 2e-7, 1e-6}) {
    Window w = testing::sine_window(static_cast<int>(2.0 / (f1 * dt)), 0.5e-9, f1, dt, 3.7e-4);
    ModalState truth = linear_steady_state(modal, 0.5e-9, f1, 0.0, w.t0_s);
    const double amplitude = std::hypot(truth.q[0], truth.v[0] / omega1);
    truth.q[0] += 0.4 * amplitude;
    truth.v[0] -= 0.3 * amplitude * omega1;
    const double moved = std::hypot(truth.q[0], truth.v[0] / omega1);
    w.deflection_m = reference_simulate(modal, ForceModelKind::none, w, testing::full_params({}, w), truth).signal;
    const ModalState est = estimate_unknown_start(modal, w, opt);
    EXPECT_NEAR(est.q[0], truth.q[0], 0.01 * moved) << "dt " << dt;
    EXPECT_NEAR(est.v[0], truth.v[0], 0.1 * moved * omega1) << "dt " << dt;
    for (int i = 1; i < modal.n_modes(); ++i) {
      EXPECT_EQ(est.q[i], linear_steady_state(modal, 0.5e-9, f1, 0.0, w.t0_s).q[i]) << "mode " << i + 1;
    }
  }
}

TEST(StartEstimateStage, TheTipsReachIsTheBaseMotionPlusTheDeflection) {
  const ModalModel modal(testing::paper_probe());
  Window w = testing::sine_window(1000, 2e-9, 25600.0, 1e-7);
  for (int n = 0; n < 1000; ++n) w.deflection_m[n] = 30e-9 * std::cos(2 * std::numbers::pi * 25600.0 * n * 1e-7);
  const double reach = *tip_reach_m(modal, w);
  // y = 2 nm sin(wt) and 30 nm cos(wt) peak together at sqrt(2^2 + 30^2) nm.
  EXPECT_NEAR(reach, std::hypot(2e-9, 30e-9), 0.01e-9);
}

// ---- the derived quantities -------------------------------------------------------------------

// A viscous contact f = -c dz/dt on z = Z cos(wt) dissipates pi c w Z^2 per period (and peaks at
// c w Z, averages 0); an elastic one f = -k z dissipates nothing, even over a window that is not
// a whole number of periods.
TEST(DerivedQuantitiesStage, ViscousAndElasticForceHistoriesInClosedForm) {
  const double f_hz = 25000, dt = 1e-7, Z = 10e-9, c = 2e-6, k = 3.0;
  const double w = 2 * std::numbers::pi * f_hz;
  const int N = static_cast<int>(3.7 / (f_hz * dt));
  std::vector<double> z(N), viscous(N), elastic(N);
  for (int n = 0; n < N; ++n) {
    const double t = n * dt;
    z[n] = Z * std::cos(w * t);
    viscous[n] = c * Z * w * std::sin(w * t);  // -c dz/dt
    elastic[n] = -k * z[n];
  }
  const ForceParams none{};
  const DerivedQuantities v = derived_quantities(ForceModelKind::none, none, viscous, z, f_hz, dt);
  EXPECT_NEAR(v.dissipated_energy_j, std::numbers::pi * c * w * Z * Z, 1e-3 * std::numbers::pi * c * w * Z * Z);
  EXPECT_NEAR(v.peak_force_n, c * w * Z, 1e-3 * c * w * Z);
  const DerivedQuantities e = derived_quantities(ForceModelKind::none, none, elastic, z, f_hz, dt);
  EXPECT_LT(std::abs(e.dissipated_energy_j), 1e-3 * k * Z * Z);
  EXPECT_NEAR(e.peak_force_n, k * Z, 1e-3 * k * Z);
}

// ---- the stream's start decision --------------------------------------------------------------

TEST(StreamContinuity, EachWindowStartsAsItsSequenceAndTheLastFitAllow) {
  EXPECT_EQ(stream_step(std::nullopt, std::nullopt), StreamStep::follows);
  EXPECT_EQ(stream_step(std::nullopt, 5), StreamStep::broken) << "the first window seen";
  EXPECT_EQ(stream_step(5, 6), StreamStep::follows);
  EXPECT_EQ(stream_step(5, 9), StreamStep::gap);
  EXPECT_EQ(stream_step(5, 5), StreamStep::broken) << "a repeat";
  EXPECT_EQ(stream_step(5, 2), StreamStep::broken) << "a restart";
  using enum StartChoice;
  for (StreamStep step : {StreamStep::follows, StreamStep::gap, StreamStep::broken})
    for (bool fit : {false, true})
      for (bool coastable : {false, true}) {
        EXPECT_EQ(decide_start(InitialState::rest, step, fit, coastable), rest);
        EXPECT_EQ(decide_start(InitialState::unknown, step, fit, coastable), cold);
        if (!fit) {
          EXPECT_EQ(decide_start(InitialState::continued, step, fit, coastable), cold);
        }
      }
  EXPECT_EQ(decide_start(InitialState::continued, StreamStep::follows, true, false), continue_fit);
  EXPECT_EQ(decide_start(InitialState::continued, StreamStep::gap, true, true), coast_then_continue);
  EXPECT_EQ(decide_start(InitialState::continued, StreamStep::gap, true, false), cold);
  EXPECT_EQ(decide_start(InitialState::continued, StreamStep::broken, true, true), cold);
}

}  // namespace
}  // namespace tipforce::inversion
