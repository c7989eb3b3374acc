"""How good a run is: errors against truth, alignment, consistency (NEES, NIS), the GPS fit."""
