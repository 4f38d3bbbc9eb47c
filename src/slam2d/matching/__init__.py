"""Scan matchers: a scan against a map, finding the pose that explains it best."""
