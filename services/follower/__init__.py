"""The reference path follower: pure pursuit along ``nav/path``, driving ``cmd/twist``."""
