#pragma once
// The inverse problem for one probe (SPEC section 2): a stream of windows, each inverted by a
// short driver over stages (lib/src/inversion/: start estimate and prior, tracking polish or
// bounded PSO, Levenberg-Marquardt polish, Gauss-Newton covariance, derived quantities), the
// forward solver reached through one batch evaluator. README "How it works" has the reasoning.
#include <chrono>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "tipforce/cantilever.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/parameters.hpp"
#include "tipforce/stream_continuity.hpp"
#include "tipforce/window.hpp"

namespace tipforce {

namespace inversion {
struct StreamState;
struct SolvePlan;
class WindowSolver;
class Deadline;
}

struct InversionOptions {
  // ---- the latency budget ----
  // At most this long (ms) per window, counted from its receipt (WindowContext::budget_start: the
  // daemon's queue wait counts), checked between batches: at the deadline the fit stops with the
  // best so far, status NOT_CONVERGED and a message that says so; being not converged it seeds
  // nothing (SPEC 5), unless resume_cut_fits. A window the deadline left unfitted altogether (it
  // spent its budget in the queue) is a gap in the stream, as a dropped one is: the previous fit
  // is coasted across it. 0: none. The default is a guard against a window that would hold up the
  // stream for seconds, not a real-time setting: it lies above the slowest ordinary fit measured
  // on a loaded 2-core machine (a cold start of a 1 MHz window with 8 modes, about a thousand
  // forward solves: p99 466 ms, README Performance), because a budget below a cold start's time
  // cascades: the cut fit seeds nothing, the next window searches cold and is cut in turn
  // (tools/bench_daemon.sh at 800/s with 2 ms: 99 % of the windows NOT_CONVERGED).
  double deadline_ms = 1000;
  // A real-time stream's way out of that cascade, against the letter of SPEC 5 (so off unless
  // asked for): the next window of the line starts cold, but its cold start first polishes from
  // the cut fit's best so far (PreviousFit::resume_values, WindowSolver::resume), as a first
  // candidate that stands only as a cold search's answer does (misfit, white residual) and is
  // given up after one step where it cannot reach the previous pixel's misfit; the cut fit's
  // start, prior and warm start are not used. tools/bench_daemon.sh at 800/s: 7-24 % of the
  // windows NOT_CONVERGED at 2 ms, 7-20 % at 1.5 ms (p99 2.2-2.6 ms), the OK answers within
  // 2 sigma as often as without a budget (README Performance). The risk it takes: a resumed
  // polish does not look at a second basin as the cold search's second cell does.
  bool resume_cut_fits = false;
  // The acquisition's sample periods (s) that Inverter::prepare readies before the first window
  // (tipforced does at start-up): the solver's step tables for a new sample period cost about
  // 5 ms at 1 MHz (8 modes, 2 cores), which the stream's first window would otherwise wait for,
  // with the windows queued behind it. Windows at other periods are still answered.
  std::vector<double> prepare_sample_periods_s;

  // ---- the swarm (lib/src/inversion/swarm.cpp) ----
  int swarm_size = 48;            // cold start
  int max_generations = 60;
  int warm_swarm_size = 12;       // warm start: seeded around the previous estimate
  int warm_max_generations = 5;
  int stall_generations = 6;      // stop the swarm when the best has not improved for this many
  double stall_rel_tolerance = 1e-4;
  // Clerc and Kennedy's constriction (2002): inertia chi = 0.7298 and acceleration chi * 2.05 =
  // 1.49618 make the particles' second-order recursion converge without a velocity limit; the
  // limit below only keeps the first generations from bouncing between the walls.
  double swarm_inertia = 0.7298;
  double swarm_acceleration = 1.49618;
  // At most this fraction of the bounds' width per generation, and a particle that hits a wall
  // keeps this fraction of its velocity, reversed (it comes back in instead of sticking there).
  double swarm_max_velocity = 0.3;
  double swarm_wall_restitution = 0.5;
  // Initial velocities uniform in +-half this (fraction of the width): a small start, so that
  // the first generation scores the stratified positions rather than where they fly to.
  double swarm_initial_velocity = 0.1;
  // A warm swarm puts half its particles around the previous estimate, this many of its sigmas
  // (in the normalised coordinates) wide: a pixel like its neighbour lies well inside, ...
  double warm_spread_sigmas = 3.0;
  // ... but at least 2 % of the width (a very sure previous fit must still see a small step) and
  // at most 25 % (an unsure one must not become a cold swarm with half the particles).
  double warm_spread_min = 0.02;
  double warm_spread_max = 0.25;
  // A previous sigma that is not finite counts as a tenth of the width (the spread is then the
  // maximum).
  double warm_spread_no_sigma = 0.1;
  // A cold swarm starts every this-many-th particle with h at the tip's reach (see swarm.cpp:
  // without them a two-period window's swarm can settle where the tip never touches).
  int reach_particle_every = 8;

  // ---- the cold physics start (lib/src/inversion/window_solver.cpp, physics_start) ----
  // A cold start (start unknown) with h among the unknowns first tries candidates from the window
  // itself (see physics_start): h at the tip's reach R (the upper bound, if lower) minus each of
  // these fractions of R - (h's lower bound), the first other unknown at the centres of
  // cold_physics_grid cells over its bounds (0: no physics start), any further one at
  // cold_physics_grid_further cells, at most cold_physics_max_candidates in all (more unknowns:
  // straight to the swarm). The indentation
  // R - h is small for a stiff contact and large for a soft one: on tipforce bench's 1 MHz line
  // (k 1 N/m) it was 14-22 nm of the 24-32 between R and 10 nm, on honesty_test's 5 MHz scan
  // (k 2-12) 0.1-1 nm; hence dense near the reach, coarser below. Measured: with 6 depths (0 to
  // 0.75) the 1 MHz line's best candidate was k 10 at a shallow depth, from which both polishes
  // crawled ~40 iterations to k 1; with 8 (0 to 0.8) its cold p50 was 14.6 ms, with these 15
  // 11.8 ms, honesty_test's cold figures as good or better. 8 x 15 = 120 candidates in one batch
  // at the swarm's coarse resolution: the cost of two and a half of the cold swarm's generations
  // of 48.
  int cold_physics_grid = 8;
  // The grid (cold and at an edge) is scored over the window's first grid_periods periods of mode
  // 1 (the whole window when it is shorter; 0: always the whole): its candidates differ by basins,
  // which a few contacts already tell apart, and the polish then fits the whole window. A 1 MHz
  // window of 1250 samples holds 31 periods: its 120 candidates took 2.5-3.0 ms over all of it,
  // 0.67-0.70 ms over the first 8 periods (tipforce bench's line, the same answers).
  double grid_periods = 8;
  std::vector<double> cold_physics_indentation_fractions = {0.0,  0.01, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2,
                                                            0.3,  0.4,  0.5,  0.6,  0.7,  0.8, 0.9};
  // A third unknown (Kelvin-Voigt's c, viscous DMT's eta) gets this many cells, evenly over its
  // bounds (log-spaced for a positive lower bound), 8 x 3 x 15 = 360 candidates. Until 2026-12-04
  // every unknown had cold_physics_grid cells, 960 > cold_physics_max_candidates, so three-unknown
  // cold starts skipped the physics start: the swarm alone cost 1190 (Kelvin-Voigt) and 1820
  // (viscous DMT) solves per cold start and left 6 of 32 of honesty_test's HonestyEveryModel 1 MHz
  // cold starts in another basin (k 14.5 and c 1.9e-5 for 4.9 N/m and 5e-6 N s/m, misfit 12 %
  // above the right answer's), reported OK.
  int cold_physics_grid_further = 3;
  int cold_physics_max_candidates = 512;
  // The polish runs from the best candidate of up to this many cells of the other unknowns (each
  // with its best h), and the lowest misfit stands. One was not enough: on honesty_test's 5 MHz
  // cold starts one window's best candidate polished into a local minimum at k 1.2 (truth 2.9)
  // with a white residual and a misfit only 5 % above the right one's (6.76e-3 against 6.47e-3).
  int cold_physics_polishes = 2;
  // ... but a later cell only when its candidate's cost is within this factor of the best's: a
  // near tie is where a second basin can hide, and a clearly worse candidate only repeats the
  // descent. Measured: honesty_test's cold figures the same at 1.5 as without the gate, 423
  // rather than 478 solves per cold start; the 1 MHz bench line's cold p50 8.1 ms against 11.8.
  double cold_physics_second_ratio = 1.5;
  // With a third unknown the grid is coarse along it and a candidate's cost predicts its basin less
  // well: on those 1 MHz cold starts the right basin's best cell cost up to 2.5 x the wrong one's.
  // Measured there (Kelvin-Voigt / viscous DMT, within 2 sigma of 32, solves per cold start): 2
  // polishes within 1.5 x 88 % / 81 %, 586 / 831; 4 within 3 x 97 % / 88 %, 874 / 1352; 6 within
  // 3 x 97 % / 87 %, 1028 / 1747; the swarm alone (before) 81 % / 81 %, 1192 / 1822.
  int cold_physics_polishes_further = 4;
  double cold_physics_second_ratio_further = 3.0;
  // The polished physics start stands when its residual's lag-1 autocorrelation is at most
  // cold_physics_max_lag1 (white noise: 0 +- 1/sqrt(N), 0.05 at N = 400; measured on honesty_test's
  // 5 MHz cold starts: right answers -0.15 to 0.13, the two wrong basins 0.38 and 0.91), or its
  // relative misfit is at most cold_physics_accept_misfit: noiseless data leave a smooth residual
  // (rho1 ~0.96) even at the right answer, the start's higher modes that the start unknowns
  // (modes 1-2) do not move: on tipforce bench's 10 MHz line the right answers left 5e-5 to
  // 1.8e-3, the wrong basins 0.19 to 0.75 (and honesty_test's 8e-3 and 1.3e-2). Otherwise the
  // swarm runs as before, from scratch.
  double cold_physics_max_lag1 = 0.3;
  double cold_physics_accept_misfit = 3e-3;

  // ---- the polish: Levenberg-Marquardt (lib/src/inversion/levenberg_marquardt.cpp) ----
  int lm_max_iterations = 20;
  // The same for a window whose start is unknown: its polish moves four start unknowns along with
  // the parameters, down a curved valley (k against h against the start amplitude) that 20
  // iterations often leave early. Measured on 64 cold starts at 5 MHz (honesty_test): the truth
  // of k within 2 sigma for 83 % of them at 20, 93 % at 100, for 2 % more forward solves.
  int cold_lm_max_iterations = 100;
  // Levenberg-Marquardt's damping (Marquardt's scaling: lambda times the diagonal). Start nearly
  // Gauss-Newton (the swarm or the grid put us close; a continued window with a start prior,
  // lm_initial_lambda_continued below, nearer still); after an accepted step relax by
  // /3, after a rejected one stiffen by x8 (asymmetric, so that a rejected step is not retried at
  // nearly the same length), and by x10 when the damped system could not be solved at all. At
  // most lm_max_tries damped solves per iteration: at x8 that spans ~14 decades of lambda.
  double lm_initial_lambda = 1e-3;
  // ... and for every polish of a continued window with a start prior (window_solver.cpp). Measured
  // on tipforce bench's 1 MHz line (200 windows; iterations per window): 1e-3 2.9, 1e-4 2.1, 1e-5
  // 1.95, 1e-6 1.96, the same windows within 2 sigma (191 of 200).
  double lm_initial_lambda_continued = 1e-5;
  double lm_lambda_down = 3.0;
  double lm_lambda_up = 8.0;
  double lm_lambda_up_singular = 10.0;
  double lm_min_lambda = 1e-12;  // below this the damping is lost in the diagonal's rounding anyway
  int lm_max_tries = 16;
  // After a rejected trial the next step's length is where the parabola through the cost and its
  // slope at the start and the trial's cost has its minimum, at least lm_min_shrink and at most
  // lm_max_shrink of the rejected step (Moré 1978: 0.1, 0.5); lambda x lm_lambda_up where that
  // parabola gives nothing (no descent along the step). Where a continued window's nearly
  // undamped first step overshot h into its bound, x 8 took 3-5 rejected trials of 8 solves
  // each; this takes one. tools/bench_daemon.sh's stream offline (1280 windows, one build,
  // toggled): 123.1 -> 108.4 solves per window (p50 96 -> 74), the same windows within 2 sigma
  // to 4 of 1280; tipforce bench's 1 MHz line unchanged (it rejects no step).
  bool lm_interpolate_rejected = true;
  double lm_min_shrink = 0.1;
  double lm_max_shrink = 0.5;
  // Marquardt's scaling damps each unknown by its own diagonal; one the window does not move at
  // all (a zero column) is damped by this instead, so that the damped matrix stays regular.
  double lm_min_diagonal = 1e-30;
  // Converged when an accepted step lowers the cost by less than this fraction (the noise's own
  // chi-square moves far more between windows) or moves no unknown by more than lm_step_tolerance
  // of its bounds' width (far below any sigma the data give).
  double lm_rel_cost_tolerance = 1e-7;
  double lm_step_tolerance = 1e-6;
  // ... or lowers the chi-square (cost / noise variance) by less than this: a step that gains
  // delta chi-square moves the estimate by about sqrt(delta) sigma, so further steps cannot change
  // the answer by more than a small fraction of its own uncertainty. 0 disables.
  double lm_chi2_tolerance = 1e-2;
  // Forward-difference step of the Jacobian, relative (at least this absolute in the normalised
  // coordinates): about the square root of the forward solver's relative error at its finest
  // (1e-12: its steps are exact for the linear part), which balances truncation against rounding.
  double jacobian_relative_step = 1e-6;
  // Geodesic acceleration of a cold start's polish steps (levenberg_marquardt.cpp: Transtrum and
  // Sethna 2012): the second directional derivative from the point and one at lm_geodesic_step x
  // the step, solved in one block, the acceleration a taken (as a / 2) when 2 |a| <=
  // lm_geodesic_alpha |step| (their step 0.1; their alpha 0.75, here 1.5). Solves per cold start
  // (deterministic; none / alpha 0.75 / alpha 1.5): tipforce bench's 1 MHz line as 64 cold starts
  // 297 / 224 / 212 (14.4 -> ~7 polish iterations: the zig-zag down the k-indentation valley);
  // bench_daemon's stream (1280 windows) line starts 248 / 286 / 250, false continuations
  // 650 / 682 / 665; the same answers throughout (59 of 64 cold windows within 2 sigma each time).
  bool lm_geodesic_acceleration = true;
  double lm_geodesic_step = 0.1;
  double lm_geodesic_alpha = 1.5;

  // ---- tracking: a continued window polished from the previous pixel ----
  // A warm, continued window keeps the polish from the previous pixel (skipping the swarm) when its
  // relative misfit is at most ratio x the previous window's + slack. With N samples of white noise
  // the misfit itself scatters by ~1/sqrt(2N) (3.5 % at N = 400), so 1.15 is ~4 such scatters: a
  // pixel like its neighbour passes, an edge or a jump (misfit up by far more) goes to the swarm.
  // The slack keeps a nearly noiseless window (misfit ~0) from failing on rounding.
  double tracking_misfit_ratio = 1.15;
  double tracking_misfit_slack = 1e-4;
  // A changed pixel: the tracking polish gives up after tracking_give_up_iterations while its
  // misfit is still above tracking_give_up_ratio x the tracking limit above and its last step
  // kept more than tracking_give_up_progress of the cost (a crawl along the valley: from a nearby
  // pixel the polish converges by far more per step; on tipforce bench's noiseless 10 MHz line,
  // whose misfits after one step were far above a limit near the model's own error, giving up on
  // the misfit alone sent every window to the candidates: 609-676 windows/s against 1067-1095).
  // Then candidates
  // along the k-h valley (below), then the grid of the cold physics start with the start
  // continued (edge_search, window_solver.cpp), then the warm swarm, each only where the one
  // before does not fit as the previous pixel did. Measured on tipforce bench's 1 MHz line (k 1 ->
  // 4 N/m, h steps of 2 nm): a full tracking polish from the other domain crawled 20 iterations
  // along the valley, failed, and the warm swarm and its polish took 260-310 solves (10-14 ms) per
  // edge, and 650 (25 ms) where it missed and the start conflict searched again cold. On
  // tools/bench_daemon.sh's stream, offline (every pixel changed: k 1-4 N/m by up to 30 % from one
  // to the next), giving up after 1, 2 and 3 iterations gave 412-548, 475 and 342-413 windows/s
  // (noisy VM, same truth within 2 sigma), the 1 MHz line as fast or faster at 1.
  int tracking_give_up_iterations = 1;
  double tracking_give_up_ratio = 2.0;
  double tracking_give_up_progress = 0.3;
  // ... and gives up before its first step when the previous answer's own linearisation predicts
  // that an exact Gauss-Newton step would fail both tests: that step was a whole linearisation
  // (8 sets) spent on learning what the prediction already said. tipforce bench's 1 MHz line's
  // domain edges predict 0.52-0.58 of the cost kept, its h steps 0.02-0.09 (tracked on): 8
  // solves fewer per edge (22.6 -> 22.1 per warm window, one build, toggled); bench_daemon's
  // stream 109.9 -> 108.4.
  bool tracking_give_up_predicted = true;
  bool edge_search = true;
  // Before the edge search, a changed pixel (the tracking polish gave up or did not fit) tries
  // candidates along the k-h valley (valley_start, window_solver.cpp): each stiffness-like unknown (positive
  // bounds) of the previous estimate times each of valley_stiffness_factors, h placed below this
  // window's reach so that the force law gives the previous peak force times each of
  // valley_force_factors at the reach; one batch, the best polished. The valley (an indentation
  // that trades against the stiffness at nearly the same peak force) is what the polish crawls
  // along from the previous pixel. Measured on tools/bench_daemon.sh's stream, offline: 246
  // windows/s (p50 3.7 ms) with the edge search alone, 369 (2.2 ms) with these candidates first.
  // The factors span x 1/4 .. 4, so that a domain edge of that contrast (a cell on its substrate,
  // the 1 / 4 N/m domains of tipforce bench's 1 MHz line) starts near its answer: over x 0.5 .. 2
  // that line's edges took the edge grid, 71-255 solves (p99 4.9 ms); over x 1/4 .. 4 in x sqrt(2)
  // rungs (27 candidates, two rounds of blocks) 75-91 (p99 2.0 ms). Then one small batch where
  // the grid's costs point (valley_refinement below), which lets the rungs be x 2 apart (15
  // candidates, one round): the edges of the 1 -> 4 N/m side had their best rung at force x 1.4,
  // the answer's peak force 2.8 x the previous pixel's, and the polish took 5 Gauss-Newton steps
  // from it. That line's edges (one build, the give-up prediction above on): x sqrt(2) rungs
  // 67-83 solves, with the refinement 62-78, x 2 rungs with it 48-58; per warm window 22.6 ->
  // 22.1, the same windows within 2 sigma. bench_daemon's stream: 107.1 solves per window
  // without the refinement, 108.4 with it (it changes every pixel by less than a rung).
  std::vector<double> valley_stiffness_factors = {0.25, 0.5, 1.0, 2.0, 4.0};
  std::vector<double> valley_force_factors = {0.7, 1.0, 1.4};
  // ... the refinement (valley_ladder.hpp: per ladder, the vertex of the parabola through the
  // best rung and its neighbours, or beyond the grid at its ends; rungs at a bound dropped).
  bool valley_refinement = true;

  // ---- the start (lib/src/inversion/start_estimate.cpp, start_prior.cpp) ----
  // An unknown start moves mode 1 to a quadratic fitted over this fraction of mode 1's period at
  // the window's beginning: short enough that a quadratic follows the oscillation there (its
  // phase moves by 45 degrees), long enough to average the noise of several samples.
  double start_fit_period_fraction = 0.125;
  // The start shifts are scaled by the window's signal rms (per mode: over its tip gain), floored
  // here: a window that is all zeros still gets finite, well-scaled coordinates.
  double min_signal_scale_m = 1e-12;
  // Floor on the standard deviation of a continued window's inherited start (modes 1-2), relative
  // to the window's signal scale: the forward solver's own error over a window (SPEC: 1e-4)
  // carried across the edge, which keeps the prior from claiming more than the model can know.
  double start_prior_floor_rel = 1e-4;
  // A continued window whose start-conflict chi-square (lib/src/inversion/start_prior.hpp: how
  // far the data pull the start from the inherited prior, in chi-square with 4 degrees of
  // freedom) exceeds this is searched again from the window alone (a cold start). If the
  // continued fit from that search's answer no longer conflicts, the continued search had only
  // missed the parameters (an edge): that fit is the answer, with a note. Otherwise, if the window
  // alone explains the data better than the continued fit (its misfit lower by more than
  // tracking_misfit_ratio), the window does not continue the previous fit (the acquisition
  // restarted, a window from elsewhere): it is answered as the cold start, with a note; if not,
  // the continued fit stands, with a note. When the window continues the
  // fit, the statistic is a chi-square with 4 degrees of freedom (median 3.4; beyond 100 with
  // probability 1e-20): on clean 2048-window scans at 5 and 1 MHz its median was 2.8-3.2 and its
  // 90th percentile 7.5, as the chi-square's. The few windows above 100 (2-5 per 1000) were edges
  // whose warm search had missed the new parameters (k 0.5 for 12 N/m at a 1 MHz rim), and at the
  // cold search's answer they gave 0.6-5. A restarted acquisition or a window from another place
  // and time gave 4e6 and more, before and after the cold search (tests/continuity_test.cpp). So
  // 100: a start pulled ten of the prior's sigmas away. Each window above it costs a cold start
  // more (2-5 per 1000 windows of a clean scan).
  double false_continuation_chi2 = 100;
  // A continued window whose tracking polish failed with a start conflict above this is not
  // searched further as a continuation (no edge grid, no warm swarm): the start-conflict test above
  // then searches it cold. 1e4: a start pulled a hundred of the prior's sigmas away, beyond the
  // edges measured above (at most a few hundred before their cold search); restarts gave 1e7.
  // The same test ends the continued fit tried again from the cold search's answer after its first
  // linearisation (WindowSolver::refuted_at_the_given_values).
  // Tried and not kept (2026-12-02, third session), to refute a false continuation before the
  // valley's polish crawls 20 iterations along it (~160 solves of its ~470): the misfit at the
  // tracked start (tools/bench_daemon.sh's smooth stream: restarts 0.21-1.85, genuine changes up
  // to 0.6 and more), its start conflict (domain edges 7e4-2.4e7, restarts 1.2e8-3e9: 5 x apart),
  // the residual before the model's first contact, where the model is free flight whatever the
  // parameters (genuine changes 2e3-6e3 chi-square per sample, restarts 3e4-2e5; on the domains
  // stream it could not be formed); none separates them by enough. Capping the valley polish at
  // 10 iterations would have sent ~25 genuine valley fits of the smooth stream's 1280 windows
  // (9-20 iterations) to the edge grid. Kept (2026-12-04): the valley's candidates themselves
  // refute it, before their polish, where they explain nothing (WindowSolver::
  // continuation_explains_nothing; the domains stream's false continuations 437 -> 194 solves).
  double continuation_refuted_chi2 = 1e4;

  // ---- pooling across pixels (lib/src/inversion/parameter_prior.cpp) ----
  // How far each unknown may move from one continued window to the next, relative to its value
  // (1 sigma of a random walk per window), by name. Empty: none; every pixel is fitted from its
  // own window (its start from the previous fit), as independent measurements. Otherwise it
  // names every unknown (each > 0), and the previous fit's parameters, with their covariance,
  // their correlation with the end state and this drift added, are a Gaussian prior that this
  // window's data update (a Kalman step on the parameters as well as the start): a window too
  // short to determine its stiffness alone (400 samples at 5 MHz: two drive periods, sigma_k/k
  // >= 12.9 % by the Cramer-Rao bound) borrows from its neighbours along the line. The price is a
  // pooled map: neighbouring pixels' errors correlate over ~ (sigma of one window / drift)^2
  // pixels, and a change of the sample smaller than about the drift plus one window's sigma is
  // smoothed over those pixels. Set each to the sample's own variation per pixel (the demo's
  // cell: k 2 % median, 6 % at the 90th percentile within its domains; h 0.35 %, at most 3 %).
  std::map<std::string, double> parameter_drift_rel;
  // A window whose own parameters differ from the prior's by more than this (the Kalman filter's
  // normalised innovation on the parameters, chi-square with one degree of freedom per unknown)
  // is not pooled: an edge of the sample, answered from its own window alone, with a note.
  // 16: exceeded by chance in 0.03-0.1 % of the windows (2-3 unknowns) where the sample does not
  // change.
  double pool_gate_chi2 = 16;
  // Levenberg-Marquardt iterations of the pooled polish, from the Kalman step's point (config
  // key pool_max_iterations). One did as well as five on the demo's 5 MHz scan (k sigma/value
  // 7.58 %, within 2 sigma 96.6 %, max/median sigma 2.5 both; errors' lag-1 correlation 0.54);
  // none (the Kalman point, linearised) did worse (within 2 sigma 94.1 %, max/median sigma of h
  // 22.3, lag-1 correlation 0.93): the Kalman step weighs the window by its HAC-inflated
  // covariance, the polish by the noise. One iteration costs a linearisation and a step: on
  // bench_daemon's 1 MHz stream 14 -> 28 solves per window at the median.
  int pool_max_iterations = 1;
  // A window beyond pool_gate_chi2 is polished once more, from the previous pixel's parameters
  // given its start, with the joint prior, for up to pool_gated_iterations (0: the linear gate
  // alone decides), and pooled there where the innovation measured on the model (the joint
  // negative log posterior there less the window's own, in chi-square units) is at most
  // pool_valley_chi2. The gate measures the innovation by the window's linearisation at its own
  // answer; where its valley is long and curved (a light contact, whose stiffness trades against
  // its depth) that answer can lie at the far end of a valley that also holds the previous
  // pixel's parameters: the demo cell at 10 MHz, k 0.5-0.7 N/m against a truth of 12, chi-square
  // 16-142 by the linearisation and 0.3-1.5 on the model. Real edges just beyond the gate measure
  // less on the model too (the demo at 5 MHz: 6.2-15.4, with the answers alone right and pooled
  // 3-6 sigma off), so the second chance asks for what an unchanged sample gives (chi-square with
  // one degree of freedom per unknown: 4 is its 86th percentile for two).
  int pool_gated_iterations = 4;
  double pool_valley_chi2 = 4;
  // A gap in the stream longer than this (samples) is not coasted across: the window after it
  // starts unknown. 50,000 samples is 40 periods of mode 1 at 1 MHz / 25 kHz (some 25 decay
  // times at Q = 100): beyond it the coasted state has forgotten the fit it came from, and the
  // coast would cost more than a cold start.
  int max_coast_samples = 50'000;
  // A gap is coasted only when the next window starts on the sample grid of the last one: within
  // this fraction of a sample period (a clock that slipped is not the same stream).
  double coast_grid_tolerance = 1e-3;

  // ---- uncertainty and reporting (lib/src/inversion/covariance.cpp, inversion.cpp) ----
  // Floor on the residual's standard deviation per sample, relative to the window's signal rms:
  // the forward solver's own error (SPEC: 1e-4), below which a smaller misfit says nothing about
  // the unknowns. It matters only for data made by this solver itself: noiseless, a smooth 10 MHz
  // line (tipforce bench) fitted to misfits of 1e-14 to 1e-11, whose variances scattered by
  // decades from one window to the next, so that the next window's chi-squares (in the previous
  // variance) reached thousands: 37 of its 200 windows failed the start-conflict test and were
  // searched again cold (~1000 solves each), and the polish ran on to the step tolerance. Real
  // detection noise (honesty_test: 0.1 nm on ~30 nm) lies an order of magnitude above it.
  double min_noise_rel = 1e-4;
  // The HAC (Bartlett) inflation of the residual variance sums the residuals' autocorrelation to
  // lag min(N x fraction, max): far enough to see the structure a misfit leaves (a mode-1 period
  // is 40-200 samples at 1-5 MHz), near enough that each lag is still estimated from many pairs.
  double hac_max_lag_fraction = 0.25;
  int hac_max_lags = 200;
  // Above this relative misfit the model does not explain the window (30 % of the signal left
  // over is far beyond any detection noise): status NOT_CONVERGED.
  double max_misfit = 0.3;
  // The Gauss-Newton matrix (at unit diagonal) counts as singular below this eigenvalue relative
  // to its largest: about where double precision stops resolving two columns from one another.
  double singular_rel_eigenvalue = 1e-13;
  // A sigma above this fraction of the bounds' own spread ((high - low) / sqrt(12)) means that the
  // window hardly narrows what the bounds already said: the estimate notes it.
  double undetermined_sigma_fraction = 0.5;
  // Pairs more correlated than this are noted as trading off (SPEC: identifiability). 0.999:
  // such a pair's sigmas are at least ~22x those either would have with the other known.
  double trade_off_correlation = 0.999;
  // An estimate within this of a bound (normalised: a billionth of the width) is noted as at it.
  double at_bound_tolerance = 1e-9;
  // An estimate with an unknown at its bound whose residual is not white (lag-1 autocorrelation
  // above this; white noise gives 0 +- 1/sqrt(N)) and above cold_physics_accept_misfit (noiseless
  // data leave a smooth residual even at the truth) is NOT_CONVERGED: the data lie outside the
  // bounds. A surface out of the tip's reach (h truly above the upper bound) was answered OK with
  // h and k at their bounds at a misfit of 0.25, whose residual's lag-1 autocorrelation was ~1;
  // a right answer's is within +-0.15 (cold_physics_max_lag1's measurements). 1: never.
  double bound_max_lag1 = 0.3;
  // Contact phase per forward-solver substep during the swarm (ForwardProblem): the global search
  // needs the basin, not 1e-4, and its candidates include stiff contacts that a fine resolution
  // would split into many substeps; the polish and the covariance use the accurate defaults
  // (default_contact_rad_per_substep, default_crossing_rad_per_substep). At 1 and 0.25 rad the
  // solver is within 7e-3 of the reference for every model from 2e-7 to 2e-6 s (the 1e-4 sweep's
  // cases from the steady state), 1.3 to 5.5 times faster than at the defaults; with crossings at
  // the contact's own level it was 4e-2 off at 1-2 MHz, more than the basins differ by.
  double search_contact_rad_per_substep = 1.0;
  double search_crossing_rad_per_substep = 0.25;
  // The swarm's random stream is seeded from this and the window's identity (window_identity):
  // a window is searched the same way whatever came before it.
  std::uint64_t seed = 1;

  // Which value is out of its range (named, with the range), or none. The Inverter refuses
  // options with a problem (std::invalid_argument); lib/src/inversion_options.cpp has the ranges.
  std::optional<std::string> problem() const;
};

enum class EstimateStatus { ok = 0, not_converged = 1, rejected = 2 };

struct Estimate {
  EstimateStatus status = EstimateStatus::ok;
  std::string message;                    // why, when status is not ok
  std::vector<std::string> names;         // the unknowns
  std::vector<double> values;
  std::vector<double> sigma;              // 1-sigma
  // Per unknown: false where the window hardly narrows what the bounds already said (its sigma is
  // near their spread); the message says so too.
  std::vector<bool> determined;
  Eigen::MatrixXd covariance;
  double misfit = 0;                      // relative L2
  double peak_force_n = 0;                // largest repulsive force magnitude
  double mean_force_n = 0;
  double max_indentation_m = 0;
  double dissipated_energy_j = 0;         // per drive period
  int iterations = 0;                     // PSO generations + LM iterations
  int forward_solves = 0;
  double solve_seconds = 0;
};

// A probe: its modal model, force model and what is known about the parameters.
struct ProbeModel {
  std::string name;
  ModalModel modal;
  ParameterSpace space;
  InversionOptions options;
  // What a window must satisfy for this probe (window_problem_for_probe). nullopt: derived from
  // the modal model as for a calibrated probe (amplitudes below 1 mm), windows up to SPEC's
  // largest. Config::probe_model gives the cantilever's length and daemon.max_window_samples.
  std::optional<WindowLimits> limits = std::nullopt;
};

// What the stream knows about a window beyond its data.
struct WindowContext {
  // The window's sequence number in its probe's stream: a gap coasts the last fit across it or
  // starts the window cold (decide_start, tipforce/stream_continuity.hpp). nullopt: the window
  // directly follows the previous one given to this Inverter.
  std::optional<std::int64_t> seq = std::nullopt;
  // When the window's latency budget (InversionOptions::deadline_ms) started counting: when it was
  // received, so that time in a queue counts. nullopt: when invert() is called.
  std::optional<std::chrono::steady_clock::time_point> budget_start = std::nullopt;
};

// Inverts the windows of one probe in order, carrying the warm start and the fitted end state
// from one window to the next. Not thread-safe; one per probe.
class Inverter {
 public:
  Inverter(ProbeModel probe, ForwardBackend& backend);
  ~Inverter();
  Inverter(Inverter&&) noexcept;
  Inverter& operator=(Inverter&&) noexcept;

  // Never throws for bad data. A window that cannot be inverted (window_problem, or
  // window_problem_for_probe against the probe's limits) gives status rejected and changes
  // nothing of the stream: to it, the window never came. Otherwise decide_start says how the
  // window starts, it is inverted (within options.deadline_ms of context.budget_start; a
  // continued window whose data do not continue the previous fit is answered as a cold start,
  // noted in the message: false_continuation_chi2), and the fit is kept for the next window as
  // far as it is trusted. A continued window the deadline left unfitted is a gap: the previous
  // fit is coasted across it. A cut fit's best so far is the next window's first candidate only
  // with options.resume_cut_fits.
  Estimate invert(const Window& window, const WindowContext& context = {});

  // Forget the warm start and end state (e.g. after a gap in the stream).
  void reset();

  // Builds what the first window at this sample period would otherwise build (the backend's
  // contact step tables, the probe's step coefficients), so that it is answered as fast as the
  // rest. Changes nothing of the stream. Throws std::invalid_argument for a period that is not
  // finite and positive.
  void prepare(double sample_period_s);

  // Advances the last fitted end state across a gap (windows that never reached the inverter) to
  // t0_s with the last estimate, so that a window after the gap can continue from it rather than
  // start unknown. False, changing nothing, when there is no state to advance, the sample period
  // differs, t0_s lies before the end state, or the gap is longer than max_gap_samples.
  // max_gap_samples < 0: the probe's options.max_coast_samples.
  bool coast_to(double t0_s, double sample_period_s, int max_gap_samples = -1);
  bool has_warm_start() const;
  // The last fit's end state (one sample period after its window's last sample), that instant on
  // the drive's clock, and the full parameter vector it was fitted with: where a prediction of
  // the next window starts (the setpoint advisor). nullptr when there is none (no fit yet, a
  // reset, a fit not trusted). Valid until the next call that changes the inverter.
  const ModalState* last_end_state() const;
  double last_end_t_s() const;
  const std::vector<double>& last_full_params() const;
  const ProbeModel& probe() const { return probe_; }
  ForwardBackend& backend() { return *backend_; }

 private:
  // The probe's step coefficients for this sample period (made when it changes).
  void use_sample_period(double sample_period_s);
  // Why the probe's modes cannot be stepped at this sample period (step_problem, which
  // make_step_coefficients enforces), nullopt if they can: a window at such a period is rejected
  // saying so, not answered with an internal error.
  std::optional<std::string> sample_period_problem(double sample_period_s) const;
  // The samples from the last fit's end state to t0_s, when it can be coasted there (see coast_to).
  std::optional<long> coast_samples(double t0_s, double sample_period_s, int max_gap_samples) const;
  Estimate invert_valid(const Window& window, const WindowContext& context, std::chrono::steady_clock::time_point t_start);
  Estimate answer_start_conflict(const Window& window, const inversion::SolvePlan& plan, inversion::WindowSolver& first,
                                 const Estimate& first_estimate);
  Estimate unanswered_false_continuation(const Estimate& first_estimate, int solves, const std::string& conflict,
                                         const std::string& why);
  inversion::Deadline deadline(const WindowContext& context, std::chrono::steady_clock::time_point t_start) const;
  std::string deadline_what(const WindowContext& context, std::chrono::steady_clock::time_point t_start) const;

  ProbeModel probe_;
  ForwardBackend* backend_;
  WindowLimits limits_;
  std::optional<std::int64_t> last_seq_;  // of the last window inverted
  // What one window hands the next, and the caches of a probe (lib/src/inversion/stream_state.hpp).
  std::unique_ptr<inversion::StreamState> state_;
};

}  // namespace tipforce
