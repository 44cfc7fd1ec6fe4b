"""The grid service: answers ``map/grid`` with the world's occupancy grid."""
