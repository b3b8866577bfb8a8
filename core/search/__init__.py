"""The search (paper section 2.3 and beyond): its state, its methods, its rounds over overlap cuts."""

from .methods import METHODS, Method
from .rounds import Round, best_round, cancelled, jaccard, polish, recut, search_rounds
from .state import SearchState

__all__ = ["METHODS", "Method", "Round", "SearchState", "best_round", "cancelled", "jaccard", "polish", "recut",
           "search_rounds"]
