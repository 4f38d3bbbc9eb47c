// Feeds a text dump of a laser log to the original GMapping (OpenSLAM's GridSlamProcessor) the way
// slam_gmapping's SlamGMapping node does, and writes the best particle's trajectory.
//
// Built and run by benchmarks/peer_gmapping.py (see its docstring); our own code, calling only
// GMapping's public API. Usage:
//
//     peer_gmapping_driver INPUT OUTPUT SEED
//
// INPUT, written by peer_gmapping.py (angles in radians, increasing; ranges in metres):
//     laser N ANGLE_MIN ANGLE_INCREMENT RANGE_MIN RANGE_MAX MOUNT_X MOUNT_Y MOUNT_THETA
//     scan T ODOM_X ODOM_Y ODOM_THETA N R1 .. RN        (one per scan, in time order; no return = RANGE_MAX)
// OUTPUT: one line per scan fed, "T X Y THETA UPDATED": the robot (base) pose in GMapping's map frame,
// UPDATED 1 when GMapping processed that scan (a node of the trajectory tree), else 0. A processed scan
// gets the best particle's node pose (its tree path walked back from the final best particle, so the
// path after every resampling); a scan in between gets the odometry since the last processed scan
// composed onto that node, as the node's map->odom transform would place it.
//
// What slam_gmapping does and this copies (slam_gmapping.cpp, initMapper / addScan / laserCallback):
// the RangeSensor "FLASER" has N beams at |angle_increment| centred on 0 (-N/2 inc .. ), pose (0,0,0),
// span 0, maxRange = range_max - 0.01; the odometry given to GMapping is the pose of the "centred" laser
// frame (the laser's mount rotated by (angle_min + angle_max) / 2) in the odometry frame; ranges below
// range_min are replaced by range_max; parameters are the node's defaults (maxUrange = maxRange);
// setgenerateMap(false); the random generator is seeded once with GMapping::sampleGaussian(1, seed)
// after init. A scan whose beam count differs from the first one is skipped, as the node does.

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include <gmapping/gridfastslam/gridslamprocessor.h>
#include <gmapping/sensor/sensor_range/rangesensor.h>
#include <gmapping/utils/stat.h>

namespace {

struct Pose {
  double x, y, theta;
};

double wrap(double a) { return std::atan2(std::sin(a), std::cos(a)); }

Pose compose(const Pose& a, const Pose& b) {
  double c = std::cos(a.theta), s = std::sin(a.theta);
  return {a.x + c * b.x - s * b.y, a.y + s * b.x + c * b.y, wrap(a.theta + b.theta)};
}

Pose inverse(const Pose& a) {
  double c = std::cos(a.theta), s = std::sin(a.theta);
  return {-c * a.x - s * a.y, s * a.x - c * a.y, wrap(-a.theta)};
}

Pose relative(const Pose& a, const Pose& b) { return compose(inverse(a), b); }

Pose from(const GMapping::OrientedPoint& p) { return {p.x, p.y, p.theta}; }

struct Fed {
  double time;
  Pose odom;      // the centred laser's odometry pose, as given to GMapping
  int last_node;  // index of the last processed scan at this scan (after it), -1 before the first
  bool updated;
};

int fail(const std::string& what) {
  std::cerr << "peer_gmapping_driver: " << what << std::endl;
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 4) return fail("usage: peer_gmapping_driver INPUT OUTPUT SEED");
  std::ifstream in(argv[1]);
  if (!in) return fail(std::string("cannot read ") + argv[1]);
  unsigned long seed = std::strtoul(argv[3], nullptr, 10);

  std::string word;
  unsigned int beams = 0;
  double angle_min = 0, angle_increment = 0, range_min = 0, range_max = 0;
  Pose mount{0, 0, 0};
  if (!(in >> word >> beams >> angle_min >> angle_increment >> range_min >> range_max >> mount.x >> mount.y >>
        mount.theta) ||
      word != "laser" || beams == 0 || angle_increment <= 0)
    return fail("the first line must be: laser N ANGLE_MIN ANGLE_INCREMENT RANGE_MIN RANGE_MAX MX MY MTHETA");

  // slam_gmapping's defaults (SlamGMapping::init, initMapper)
  const double maxRange = range_max - 0.01, maxUrange = maxRange;
  const double sigma = 0.05, lstep = 0.05, astep = 0.05, lsigma = 0.075, ogain = 3.0;
  const int kernelSize = 1, iterations = 5, lskip = 0, particles = 30;
  const double minimumScore = 0.0;
  const double srr = 0.1, srt = 0.2, str = 0.1, stt = 0.2;
  const double linearUpdate = 1.0, angularUpdate = 0.5, temporalUpdate = -1.0, resampleThreshold = 0.5;
  const double xmin = -100.0, ymin = -100.0, xmax = 100.0, ymax = 100.0, delta = 0.05;
  const double llsamplerange = 0.01, llsamplestep = 0.01, lasamplerange = 0.005, lasamplestep = 0.005;

  // The centred laser frame: the laser's mount, turned to the middle of its field of view.
  const double angle_max = angle_min + angle_increment * (beams - 1);
  const Pose centred = compose(mount, Pose{0, 0, (angle_min + angle_max) / 2});

  GMapping::GridSlamProcessor gsp;
  GMapping::RangeSensor* laser =
      new GMapping::RangeSensor("FLASER", beams, std::fabs(angle_increment), GMapping::OrientedPoint(0, 0, 0), 0.0,
                                maxRange);
  GMapping::SensorMap smap;
  smap.insert(std::make_pair(laser->getName(), laser));
  gsp.setSensorMap(smap);

  std::vector<Fed> fed;
  std::vector<double> ranges(beams);
  bool initialised = false;
  int processed = 0;
  std::string line;
  std::getline(in, line);  // the rest of the laser line
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::istringstream ls(line);
    double t;
    Pose odom;
    unsigned int n;
    if (!(ls >> word >> t >> odom.x >> odom.y >> odom.theta >> n) || word != "scan")
      return fail("bad scan line: " + line.substr(0, 80));
    std::vector<double> raw(n);
    for (unsigned int i = 0; i < n; ++i)
      if (!(ls >> raw[i])) return fail("scan line ends early at t=" + std::to_string(t));
    if (n != beams) continue;  // slam_gmapping's addScan: a different beam count is not processed
    // "Must filter out short readings, because the mapper won't"
    for (unsigned int i = 0; i < n; ++i) ranges[i] = raw[i] < range_min ? range_max : raw[i];
    // getOdomPose: the centred laser's pose in the odometry frame
    Pose laser_odom = compose(odom, centred);
    GMapping::OrientedPoint gmap_pose(laser_odom.x, laser_odom.y, laser_odom.theta);
    if (!initialised) {  // initMapper, at the first scan
      gsp.setMatchingParameters(maxUrange, maxRange, sigma, kernelSize, lstep, astep, iterations, lsigma, ogain,
                                lskip);
      gsp.setMotionModelParameters(srr, srt, str, stt);
      gsp.setUpdateDistances(linearUpdate, angularUpdate, resampleThreshold);
      gsp.setUpdatePeriod(temporalUpdate);
      gsp.setgenerateMap(false);
      gsp.GridSlamProcessor::init(particles, xmin, ymin, xmax, ymax, delta, gmap_pose);
      gsp.setllsamplerange(llsamplerange);
      gsp.setllsamplestep(llsamplestep);
      gsp.setlasamplerange(lasamplerange);
      gsp.setlasamplestep(lasamplestep);
      gsp.setminimumScore(minimumScore);
      GMapping::sampleGaussian(1, seed);  // "Call the sampling function once to set the seed."
      initialised = true;
    }
    GMapping::RangeReading reading(beams, ranges.data(), laser, t);
    reading.setPose(gmap_pose);
    bool updated = gsp.processScan(reading);
    if (updated) ++processed;
    fed.push_back({t, laser_odom, processed - 1, updated});
  }
  if (fed.empty()) return fail("no scan with the first line's beam count");

  // The best particle's path: its tree nodes from the root to its current node, one per processed scan.
  const GMapping::GridSlamProcessor::Particle& best = gsp.getParticles()[gsp.getBestParticleIndex()];
  std::vector<const GMapping::GridSlamProcessor::TNode*> chain;
  for (const GMapping::GridSlamProcessor::TNode* n = best.node; n; n = n->parent)
    if (n->reading) chain.push_back(n);
  if (static_cast<int>(chain.size()) != processed)
    return fail("the best particle's path has " + std::to_string(chain.size()) + " nodes for " +
                std::to_string(processed) + " processed scans");
  std::vector<Pose> nodes;
  std::vector<double> node_times;
  for (auto it = chain.rbegin(); it != chain.rend(); ++it) {
    nodes.push_back(from((*it)->pose));
    node_times.push_back((*it)->reading->getTime());
  }

  std::FILE* out = std::fopen(argv[2], "w");
  if (!out) return fail(std::string("cannot write ") + argv[2]);
  const Pose base_from_centred = inverse(centred);
  std::vector<Pose> node_odom(nodes.size());
  for (const Fed& f : fed)
    if (f.updated) node_odom[f.last_node] = f.odom;
  for (const Fed& f : fed) {
    if (f.last_node < 0) continue;
    if (f.updated && std::fabs(node_times[f.last_node] - f.time) > 1e-9) {
      std::fclose(out);
      return fail("node " + std::to_string(f.last_node) + " is not the scan at t=" + std::to_string(f.time));
    }
    Pose laser_map = compose(nodes[f.last_node], relative(node_odom[f.last_node], f.odom));
    Pose base = compose(laser_map, base_from_centred);
    std::fprintf(out, "%.6f %.9f %.9f %.9f %d\n", f.time, base.x, base.y, base.theta, f.updated ? 1 : 0);
  }
  std::fclose(out);
  return 0;
}
