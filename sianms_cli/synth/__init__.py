"""The synthetic world: object shapes and looks, camera renderer and LiDAR ray caster."""
