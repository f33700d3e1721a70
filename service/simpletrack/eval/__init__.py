"""Evaluation: KITTI (AB3DMOT's rules), CLEAR MOT scoring, nuScenes parity, preset tuning."""
