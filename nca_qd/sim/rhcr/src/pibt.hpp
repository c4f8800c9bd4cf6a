// Lifelong PIBT (Okumura et al., "Priority Inheritance with Backtracking for Iterative
// Multi-agent Path Finding", AIJ 2022): a second exact simulator beside RHCR, with RHCR's task
// model and congestion rule, so that a layout can be judged under both planners.
//
// Every timestep each agent, in order of priority (timesteps since its current goal was
// assigned, then a random tie-breaker drawn once per agent), takes the free neighbouring cell
// (or its own) nearest to its goal; an agent standing on the cell it wants is asked to move
// first, inheriting the asker's priority, and backtracks if it cannot (no vertex or swap
// conflicts, one step per call, no window). Agents dwelling at a station stay. RHCR's rule
// stops a run as congested: more than half of the agents stood still, not dwelling, through a
// round of h (`replan`) steps.
#pragma once

#include "rhcr.hpp"

namespace rhcr {

// Runs one simulation with PIBT as the planner (window, PBS and A* settings unused); with
// `swap`, PIBT with swap (LaCAM3's PIBT: pairs that must pass each other in a one-lane corridor
// back up to a branch; see pibt.cpp).
SimResult simulate_pibt(const SimConfig& cfg, bool swap = false);

}  // namespace rhcr
