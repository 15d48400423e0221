"""Zenoh side of the bridge: keys, protobuf messages, sessions, publishing, subscribing."""
