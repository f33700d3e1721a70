"""MCAP recordings of what travels on Zenoh: raw payloads with the wire's JSON Schemas, and
Foxglove's JSON and SceneUpdate twins (writer.py; replayed by ``simpletrack replay mcap``)."""
