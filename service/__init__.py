"""SimpleTrack streaming service: the pure tracker core (service.core) and its Zenoh edges."""
