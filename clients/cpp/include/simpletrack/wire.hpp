// SimpleTrack wire codec (schemas/README.md): header-only, C++17, on msgpack-c++ (4.x or
// newer). DetectionFrame versions 1 and 2 (extrinsic), TrackFrame 1 to 3 (3: the custody
// epoch), FrameError, and a vehicle's fused tracks (VehicleTrackFrame 1 and 2,
// wire/vehicle_tracks.hpp); simpletrack::EpochFilter drops what a fenced holder of a tracks
// stream sends (wire/epoch_filter.hpp), simpletrack::StreamFilter that and exact repeats too
// (wire/stream_filter.hpp: the subscribers' rule).
//
//   #include <simpletrack/wire.hpp>
//   namespace wire = simpletrack::wire;
//   std::vector<std::uint8_t> bytes = wire::encode(frame);        // DetectionFrame, TrackFrame,
//   FrameError auto tracks = wire::decode_track_frame(data, size);           // Result<TrackFrame>
//   if (!tracks) log(tracks.error().message());                   // e.g. "column_length at
//   tracks.yaw: ..."
#pragma once

#include "simpletrack/wire/bytes.hpp"
#include "simpletrack/wire/decode.hpp"
#include "simpletrack/wire/encode.hpp"
#include "simpletrack/wire/epoch_filter.hpp"
#include "simpletrack/wire/messages.hpp"
#include "simpletrack/wire/stream_filter.hpp"
#include "simpletrack/wire/vehicle_tracks.hpp"
