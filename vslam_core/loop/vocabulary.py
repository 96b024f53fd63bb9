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

import numpy as np

KMAJORITY_ITERATIONS = 3
MAX_TRAINING = 4000  # descriptors the centres are refined on (a deterministic sample)
BRANCHES = 32  # clusters of the tree's first level


def hamming(descriptors: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(N, C) int32 Hamming distances between (N, 32) and (C, 32) uint8 descriptors, or (N, C, 32) centres of
    each descriptor's own: popcount of the XOR of their four 64-bit words."""
    words = np.ascontiguousarray(descriptors).view(np.uint64)  # (N, 4)
    against = np.ascontiguousarray(centres).view(np.uint64)
    against = against[None] if against.ndim == 2 else against  # (1 or N, C, 4)
    distances = np.bitwise_count(words[:, None, 0] ^ against[..., 0]).astype(np.int32)
    for word in range(1, 4):  # word by word: 5x faster than a sum over the last axis of (N, C, 4) counts
        distances += np.bitwise_count(words[:, None, word] ^ against[..., word])
    return distances


def nearest(descriptors: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(N,) index of the nearest (Hamming) of the (C, 32) centres for each (N, 32) descriptor; ties: the first
    (as OpenCV's brute-force matcher, which this replaces: the same words, without its per-match objects)."""
    if len(descriptors) == 0 or len(centres) == 0:
        return np.zeros(len(descriptors), np.int64)
    return np.asarray(np.argmin(hamming(descriptors, centres), axis=1), np.int64)


def kmajority(pool: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """(min(count, N), 32) uint8 centres of the (N, 32) descriptors: drawn from them, then `KMAJORITY_ITERATIONS`
    times each centre replaced by the bitwise majority of the descriptors nearest to it (an empty one stays)."""
    count = min(count, len(pool))
    centres = pool[np.sort(rng.choice(len(pool), count, replace=False))]
    bits = np.unpackbits(pool, axis=1)  # (N, 256) uint8; summed in int32 (as int32 it was a 16.6 MB peak, now 6.3)
    for _ in range(KMAJORITY_ITERATIONS):
        assigned = nearest(pool, centres)
        order = np.argsort(assigned, kind="stable")
        used, starts, members = np.unique(assigned[order], return_index=True, return_counts=True)
        sums = np.add.reduceat(bits[order], starts, axis=0, dtype=np.int32)  # (used, 256) bit counts
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
        # (B, W, 32) each branch's words padded to the widest branch (W words), and (B, W) which are real
        width = int(np.diff(offsets).max())
        slots = offsets[:-1, None] + np.arange(width)  # (B, W)
        self._real = slots < offsets[1:, None]
        self._branch_words = words[np.where(self._real, slots, 0)]

    @classmethod
    def build(cls, documents: list[np.ndarray], words: int, seed: int) -> BinaryVocabulary:
        """From the (N_i, 32) uint8 descriptors of a few keyframes (the documents): about `words` leaves (fewer if
        there are fewer descriptors), idf = log(documents / documents containing the word)."""
        pool = np.concatenate(documents)
        rng = np.random.default_rng(seed)
        if len(pool) > MAX_TRAINING:
            pool = pool[np.sort(rng.choice(len(pool), MAX_TRAINING, replace=False))]
        branches = kmajority(pool, min(BRANCHES, words), rng)
        assigned = nearest(pool, branches)
        per_branch = max(words // len(branches), 1)
        leaves = [kmajority(pool[assigned == b], per_branch, rng) if (assigned == b).any()
                  else branches[b:b + 1] for b in range(len(branches))]
        offsets = np.concatenate(([0], np.cumsum([len(leaf) for leaf in leaves])))
        vocabulary = cls(np.concatenate(leaves), np.ones(int(offsets[-1])), branches, offsets)
        seen = np.zeros(len(vocabulary.words))
        for document in documents:
            seen[np.unique(vocabulary.assign(document))] += 1
        vocabulary.idf = np.log(len(documents) / np.maximum(seen, 1.0)) + 1e-3
        return vocabulary

    def assign(self, descriptors: np.ndarray) -> np.ndarray:
        """(N,) word index of each (N, 32) descriptor: its nearest branch, then that branch's nearest word (ties:
        the first), all descriptors at once."""
        if len(descriptors) == 0:
            return np.zeros(0, np.int64)
        branch = nearest(descriptors, self.branches)
        distances = hamming(descriptors, self._branch_words[branch])  # (N, W)
        distances[~self._real[branch]] = np.iinfo(np.int32).max  # the padding is never nearest
        return np.asarray(self.offsets[branch] + np.argmin(distances, axis=1), np.int64)

    def vector(self, descriptors: np.ndarray) -> np.ndarray:
        """(V,) float64 tf-idf bag of words, L1-normalised (zeros without descriptors)."""
        histogram = np.bincount(self.assign(descriptors), minlength=len(self.words)).astype(np.float64)
        weighted = histogram / max(len(descriptors), 1) * self.idf
        total = weighted.sum()
        return weighted / total if total > 0 else weighted


def similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """L1 score 1 − ½‖a − b‖₁ of (V,) vector a against (V,) or (N, V) b (Gálvez-López & Tardós 2012, eq. 2)."""
    return np.asarray(1.0 - 0.5 * np.abs(b - a).sum(axis=-1))
