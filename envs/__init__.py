"""Truth plant, road, sensors, scenarios and Gymnasium environments of fourwis."""
