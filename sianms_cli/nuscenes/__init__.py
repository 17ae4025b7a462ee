"""The nuScenes v1.0 on-disk format: schema, indexed loader, writer, splits, sensor files.

Knows nothing of torch. Points are row-major (N, 3+) arrays, not the devkit's 3xN; frames and
units follow nuScenes (metres, radians, quaternions w, x, y, z; global -> ego -> sensor).
Import the modules themselves (``sianms_cli.nuscenes.loader``, ...): this package imports
nothing, so the command line starts without loading numpy.
"""
