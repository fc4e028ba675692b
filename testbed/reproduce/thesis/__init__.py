"""The thesis's abstract single-target studies (no highway-env, no LiDAR)."""
