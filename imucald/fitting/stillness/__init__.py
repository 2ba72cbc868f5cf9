"""From samples to still poses: the stillness detector, its noise floor, repeated samples, pose
averaging and the pose file."""
