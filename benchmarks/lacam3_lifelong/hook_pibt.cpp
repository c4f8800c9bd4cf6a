// The hooked build of Kei18/lacam3's PIBT, for the replay mode of
// benchmarks/check_pibt_swap_reference.py: lacam3's own src/pibt.cpp, included from the checkout
// at build time (never copied here) and compiled as it is, except that its one tie-breaker draw
// goes to tie_hook (driver.cpp), which can return lacam3's own draw or nca-qd's candidate order.
// With that order fed in, nothing else of lacam3's PIBT with swap is replaced, so a difference
// between the two planners' paths is a difference in their PIBT-with-swap logic.
// Build with -DHOOKED -I<lacam3>/lacam3/include -I<lacam3>/lacam3/src; the Python module checks
// first that pibt.cpp has exactly the one draw this expects (at lacam3 commit 1a269b7: in
// funcPIBT, one call per neighbour u of agent i).
#include <random>

#include "pibt.hpp"

float tie_hook(PIBT* self, int i, Vertex* u, std::mt19937& mt);

#define get_random_float(MT) tie_hook(this, i, u, MT)
#include "pibt.cpp"
#undef get_random_float
