#include "simstack/offline/piles/household.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "simstack/assert.h"

namespace simstack {

std::vector<std::shared_ptr<const ObjectShape>> containerCatalogue(int count) {
  if (count < 1) throw std::invalid_argument("containerCatalogue: count must be >= 1");
  std::mt19937_64 rng(0xB0B1C0FFEEull);
  const auto draw = [&](double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng);
  };
  std::vector<std::shared_ptr<const ObjectShape>> out;
  for (int i = 0; i < count; ++i) {
    ContainerSpec c;
    if (i % 2 == 0) {  // a bowl
      c.radius_top_m = draw(0.055, 0.095);
      c.radius_bottom_m = c.radius_top_m * draw(0.45, 0.7);
      c.height_m = draw(0.04, 0.08);
    } else {  // a cup or mug
      c.radius_top_m = draw(0.035, 0.05);
      c.radius_bottom_m = c.radius_top_m * draw(0.75, 1.0);
      c.height_m = draw(0.07, 0.12);
    }
    c.wall_m = draw(0.004, 0.008);
    // The name keeps 0.1 mm: build from the rounded sizes, so that a dataset's name rebuilds
    // exactly this shape.
    const auto rounded = parseContainerName(c.name());
    SIMSTACK_ASSERT(rounded.has_value(), "containerCatalogue drew an invalid container");
    out.push_back(ObjectShape::fromContainer(*rounded, i));
  }
  return out;
}

SuperquadricShape householdSuperquadric(std::mt19937_64& rng, double min_exponent,
                                        double max_exponent) {
  const auto draw = [&](double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng);
  };
  Vec3 extent;
  switch (std::uniform_int_distribution<int>(0, 2)(rng)) {
    case 0:  // flat: plates, books, boxes lying on a face
      extent = Vec3(draw(0.06, 0.22), draw(0.06, 0.22), draw(0.012, 0.03));
      break;
    case 1:  // thin and long: pens, tools, bottles lying down
      extent = Vec3(draw(0.1, 0.25), draw(0.015, 0.045), draw(0.015, 0.045));
      break;
    default:  // small: caps, fruit, plugs
      extent = Vec3(draw(0.025, 0.05), draw(0.025, 0.05), draw(0.025, 0.05));
      break;
  }
  std::uniform_real_distribution<double> log_e(std::log(min_exponent), std::log(max_exponent));
  SuperquadricShape sq;
  for (int i = 0; i < 3; ++i) {
    sq.scale_m[i] = 0.5 * extent[i];
    sq.exponents[i] = std::exp(log_e(rng));
  }
  return sq;
}

}  // namespace simstack
