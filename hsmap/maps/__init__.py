"""Maps: occupancy grids and their files (:mod:`~hsmap.maps.grid`), voxel maps of the SLAM run
(:mod:`~hsmap.maps.mapping`), 3D occupancy maps in and out, the floor and height bands
(:mod:`~hsmap.maps.maps3d`), and the 2D <-> 3D registration and overlay (:mod:`~hsmap.maps.fusion`)."""
