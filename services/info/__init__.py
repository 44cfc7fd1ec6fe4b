"""info: answers ``icefloe/<robot>/info`` with what this robot is (the smallest icefloe service)."""
