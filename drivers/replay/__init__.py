"""Recorded files: readers for AEDAT 4/3.1/2.0, ROS bags, text and HDF5, and the crash-safe native recorder (issue 7)."""
