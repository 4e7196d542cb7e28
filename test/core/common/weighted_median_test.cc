// WeightedMedian: the value at which the weights reach half their sum.
#include "deblur_sr_mvs/core/common/weighted_median.h"

#include <gtest/gtest.h>

namespace deblur_sr_mvs {
namespace {

TEST(WeightedMedian, HalfTheWeightOrThePlainMedian) {
  EXPECT_EQ(WeightedMedian({}), 0.0);
  EXPECT_EQ(WeightedMedian({{3.0, 1.0}}), 3.0);
  // Equal weights: the lower median, in any order.
  EXPECT_EQ(WeightedMedian({{5.0, 1.0}, {1.0, 1.0}, {3.0, 1.0}}), 3.0);
  // A heavy sample outweighs the rest.
  EXPECT_EQ(WeightedMedian({{0.0, 1.0}, {0.02, 10.0}, {0.03, 1.0}}), 0.02);
  EXPECT_EQ(WeightedMedian({{0.0, 5.0}, {0.02, 1.0}, {0.03, 1.0}}), 0.0);
  // Zero and negative weights do not count, unless no weight does.
  EXPECT_EQ(WeightedMedian({{0.0, 0.0}, {0.02, 1.0}, {0.03, -4.0}}), 0.02);
  EXPECT_EQ(WeightedMedian({{7.0, 0.0}, {2.0, 0.0}, {4.0, 0.0}}), 4.0);
}

}  // namespace
}  // namespace deblur_sr_mvs
