"""Dataset and result-file formats: KITTI and nuScenes detections and labels, track files, recordings."""
