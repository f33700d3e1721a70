"""A simulated fleet with ground truth, and the demo that runs it against a real service."""
