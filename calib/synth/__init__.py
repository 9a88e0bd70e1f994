"""Synthetic vineyard and urban worlds with every ground truth, written in the KITTI odometry
layout (``supportnet synth``; configs in ``calib/defaults/synth``)."""
