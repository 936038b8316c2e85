"""Offline replay: a recorded bag through the stream engine, its first-pass streams, batch workers, live/offline compare."""
