"""Element links (SPEC §8): per pair of original elements, the link of their roots refined down the
split trees until each link carries little light. `master` is the link stage (plan, tasks,
store), `refine` the numba refinement over a task's local node table (`nodes`), `sampling` the
stratified visibility rays of a link, and `formfactors` the oracle's and the links' form
factors."""
