#pragma once
/// @file grasp_files.h
/// What a grasp ranking leaves for people and programs: a printed table, a JSON of every
/// grasp and its outcomes, and a picture of the best grasps drawn on the scene.

#include <string>
#include <vector>

#include "simstack/grasping/grasp_ranking.h"

namespace simstack {

/// The ranking as a text table of its first `rows` grasps (rank, contact, approach, seal,
/// displacements in mm, toppled, freed, failed), then the baseline drift.
std::string graspTable(const GraspRanking& ranking, int rows);

/// JSON: target id, candidate counts, baseline per hypothesis, and every grasp best first with
/// its tool and pre-grasp poses (toolPose(), pregraspPose() `pregrasp_distance_m` back; the
/// scene's frame, [x, y, z, qw, qx, qy, qz]) and per-hypothesis outcomes. Throws
/// std::runtime_error naming the file when it cannot write.
void writeGraspJson(const std::string& path, const GraspRanking& ranking, int target_id,
                    double pregrasp_distance_m);

/// The scene seen from above and in front (640x480), with the first `top` grasps as arrows
/// pointing at their contacts, numbered by rank, coloured by outcome as the grasp server's
/// markers are: green held and freed in every hypothesis, yellow held, red the seal broke.
void writeGraspPicture(const std::string& path, const std::vector<SuperquadricShape>& scene,
                       const std::vector<RankedGrasp>& grasps, int top);

}  // namespace simstack
