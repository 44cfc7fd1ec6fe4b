"""Cameras, shared by the camera service, the lab's overhead localizer, the simulator's cameras and
``icefloe calibrate``: the camera model (`geometry`, `overhead`), calibration boards
(`calibration`), ArUco dictionaries (`aruco`), where frames come from (`sources`) and the capture
thread that reads them (`capture`)."""
