"""A bag of binary words built from the run's own ORB descriptors (nothing downloaded), as a two-level
vocabulary tree.

Words: the descriptors are split into `BRANCHES` clusters by k-majority (the binary counterpart of k-means: each
centre becomes the bitwise majority of the descriptors nearest to it in Hamming distance; Grana et al., "A Fast
Approach for Integrating ORB Descriptors in the Bag of Words Model", 2013), and each cluster again into up to
`words / BRANCHES` words: the leaves are the words. A descriptor's word is found down the tree (its nearest
branch, then its nearest word in that branch: 2·√V distances instead of V, as DBoW2's vocabulary trees do;
Gálvez-López & Tardós, "Bags of Binary Words for Fast Place Recognition in Image Sequences", T-RO 2012). A
keyframe's vector is its word histogram weighted by tf-idf and L1-normalised; two vectors score
s = 1 − ½‖v₁ − v₂‖₁ ∈ [0, 1] (ibid., eq. 2).
"""

from __future__ import annotations

import cv2
import numpy as np

KMAJORITY_ITERATIONS = 3
MAX_TRAINING = 4000  # descriptors the centres are refined on (a deterministic sample)
BRANCHES = 32  # clusters of the tree's first level


def nearest(descriptors: np.ndarray, centres: np.ndarray, matcher: cv2.BFMatcher) -> np.ndarray:
    """(N,) index of the nearest (Hamming) of the (C, 32) centres for each (N, 32) descriptor."""
    found = np.zeros(len(descriptors), np.int64)
    if len(descriptors) == 0 or len(centres) == 0:
        return found
    for match in matcher.match(descriptors, centres):
        found[match.queryIdx] = match.trainIdx
    return found


def kmajority(pool: np.ndarray, count: int, rng: np.random.Generator, matcher: cv2.BFMatcher) -> np.ndarray:
    """(min(count, N), 32) uint8 centres of the (N, 32) descriptors: drawn from them, then `KMAJORITY_ITERATIONS`
    times each centre replaced by the bitwise majority of the descriptors nearest to it (an empty one stays)."""
    count = min(count, len(pool))
    centres = pool[np.sort(rng.choice(len(pool), count, replace=False))]
    bits = np.unpackbits(pool, axis=1).astype(np.int32)
    for _ in range(KMAJORITY_ITERATIONS):
        assigned = nearest(pool, centres, matcher)
        order = np.argsort(assigned, kind="stable")
        used, starts, members = np.unique(assigned[order], return_index=True, return_counts=True)
        sums = np.add.reduceat(bits[order], starts, axis=0)  # (used, 256) bit counts
        centres = centres.copy()
        centres[used] = np.packbits((2 * sums > members[:, None]).astype(np.uint8), axis=1)
    return centres


class BinaryVocabulary:
    """(V, 32) uint8 word centres (the tree's leaves, branch by branch), (V,) idf weights, and the tree's first
    level: (B, 32) branch centres and the (B + 1,) offsets of each branch's words in `words`."""

    def __init__(self, words: np.ndarray, idf: np.ndarray, branches: np.ndarray, offsets: np.ndarray) -> None:
        self.words = words
        self.idf = idf
        self.branches = branches
        self.offsets = offsets
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)

    @classmethod
    def build(cls, documents: list[np.ndarray], words: int, seed: int) -> BinaryVocabulary:
        """From the (N_i, 32) uint8 descriptors of a few keyframes (the documents): about `words` leaves (fewer if
        there are fewer descriptors), idf = log(documents / documents containing the word)."""
        pool = np.concatenate(documents)
        rng = np.random.default_rng(seed)
        if len(pool) > MAX_TRAINING:
            pool = pool[np.sort(rng.choice(len(pool), MAX_TRAINING, replace=False))]
        matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        branches = kmajority(pool, min(BRANCHES, words), rng, matcher)
        assigned = nearest(pool, branches, matcher)
        per_branch = max(words // len(branches), 1)
        leaves = [kmajority(pool[assigned == b], per_branch, rng, matcher) if (assigned == b).any()
                  else branches[b:b + 1] for b in range(len(branches))]
        offsets = np.concatenate(([0], np.cumsum([len(leaf) for leaf in leaves])))
        vocabulary = cls(np.concatenate(leaves), np.ones(int(offsets[-1])), branches, offsets)
        seen = np.zeros(len(vocabulary.words))
        for document in documents:
            seen[np.unique(vocabulary.assign(document))] += 1
        vocabulary.idf = np.log(len(documents) / np.maximum(seen, 1.0)) + 1e-3
        return vocabulary

    def assign(self, descriptors: np.ndarray) -> np.ndarray:
        """(N,) word index of each (N, 32) descriptor: its nearest branch, then that branch's nearest word."""
        branch = nearest(descriptors, self.branches, self._matcher)
        word = np.zeros(len(descriptors), np.int64)
        for b in np.unique(branch).tolist():
            rows = np.flatnonzero(branch == b)
            start, stop = int(self.offsets[b]), int(self.offsets[b + 1])
            word[rows] = start + nearest(descriptors[rows], self.words[start:stop], self._matcher)
        return word

    def vector(self, descriptors: np.ndarray) -> np.ndarray:
        """(V,) float64 tf-idf bag of words, L1-normalised (zeros without descriptors)."""
        histogram = np.bincount(self.assign(descriptors), minlength=len(self.words)).astype(np.float64)
        weighted = histogram / max(len(descriptors), 1) * self.idf
        total = weighted.sum()
        return weighted / total if total > 0 else weighted


def similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """L1 score 1 − ½‖a − b‖₁ of (V,) vector a against (V,) or (N, V) b (Gálvez-López & Tardós 2012, eq. 2)."""
    return np.asarray(1.0 - 0.5 * np.abs(b - a).sum(axis=-1))
