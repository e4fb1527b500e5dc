#pragma once
/// @file household.h
/// Shapes of real table clutter that the paper's random superquadrics (5-30 cm boxes and
/// ellipsoids) never draw: bowls and cups (concave, as meshes), plates and books (flat), pens
/// and bottles lying down (thin and long), and small items of 2-5 cm.

#include <memory>
#include <random>
#include <vector>

#include "simstack/geometry/superquadric.h"
#include "simstack/scene/scene.h"

namespace simstack {

/// `count` containers, alternately a bowl (wide opening, tapered, 4-8 cm high) and a cup
/// (straight or slightly tapered, 7-12 cm high), with catalogue indices 0..count-1. The same
/// list on every call (a fixed seed), so a dataset's mesh names rebuild it.
std::vector<std::shared_ptr<const ObjectShape>> containerCatalogue(int count = 32);

/// One flat, thin or small superquadric (a third each) with exponents log-uniform in
/// [min_exponent, max_exponent].
SuperquadricShape householdSuperquadric(std::mt19937_64& rng, double min_exponent,
                                        double max_exponent);

}  // namespace simstack
