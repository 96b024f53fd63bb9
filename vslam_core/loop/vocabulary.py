"""A bag of binary words built from the run's own ORB descriptors (nothing downloaded).

Words: `words` centres drawn from the first keyframes' descriptors, refined by k-majority iterations (the
binary counterpart of k-means: each centre becomes the bitwise majority of the descriptors nearest to it in
Hamming distance; Grana et al., "A Fast Approach for Integrating ORB Descriptors in the Bag of Words Model",
2013). A keyframe's vector is its word histogram weighted by tf-idf and L1-normalised; two vectors score
s = 1 − ½‖v₁ − v₂‖₁ ∈ [0, 1] (Gálvez-López & Tardós, "Bags of Binary Words for Fast Place Recognition in Image
Sequences", T-RO 2012, eq. 2).
"""

from __future__ import annotations

import cv2
import numpy as np

KMAJORITY_ITERATIONS = 3
MAX_TRAINING = 4000  # descriptors the centres are refined on (a deterministic sample)


class BinaryVocabulary:
    """(V, 32) uint8 word centres and (V,) idf weights."""

    def __init__(self, words: np.ndarray, idf: np.ndarray) -> None:
        self.words = words
        self.idf = idf
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)

    @classmethod
    def build(cls, documents: list[np.ndarray], words: int, seed: int) -> BinaryVocabulary:
        """From the (N_i, 32) uint8 descriptors of a few keyframes (the documents): `words` centres (fewer if
        there are fewer descriptors), idf = log(documents / documents containing the word)."""
        pool = np.concatenate(documents)
        rng = np.random.default_rng(seed)
        if len(pool) > MAX_TRAINING:
            pool = pool[np.sort(rng.choice(len(pool), MAX_TRAINING, replace=False))]
        count = min(words, len(pool))
        centres = pool[np.sort(rng.choice(len(pool), count, replace=False))]
        vocabulary = cls(centres, np.ones(count))
        pool_bits = np.unpackbits(pool, axis=1)
        for _ in range(KMAJORITY_ITERATIONS):
            nearest = vocabulary.assign(pool)
            order = np.argsort(nearest, kind="stable")
            used, starts, members = np.unique(nearest[order], return_index=True, return_counts=True)
            sums = np.add.reduceat(pool_bits[order].astype(np.int32), starts, axis=0)  # (used, 256) bit counts
            centres = centres.copy()  # an empty word keeps its centre
            centres[used] = np.packbits((2 * sums > members[:, None]).astype(np.uint8), axis=1)
            vocabulary = cls(centres, np.ones(count))
        seen = np.zeros(count)
        for document in documents:
            seen[np.unique(vocabulary.assign(document))] += 1
        return cls(centres, np.log(len(documents) / np.maximum(seen, 1.0)) + 1e-3)

    def assign(self, descriptors: np.ndarray) -> np.ndarray:
        """(N,) index of the nearest word (Hamming) of each (N, 32) descriptor."""
        if len(descriptors) == 0:
            return np.zeros(0, np.int64)
        matches = self._matcher.match(descriptors, self.words)
        nearest = np.zeros(len(descriptors), np.int64)
        for match in matches:
            nearest[match.queryIdx] = match.trainIdx
        return nearest

    def vector(self, descriptors: np.ndarray) -> np.ndarray:
        """(V,) float64 tf-idf bag of words, L1-normalised (zeros without descriptors)."""
        histogram = np.bincount(self.assign(descriptors), minlength=len(self.words)).astype(np.float64)
        weighted = histogram / max(len(descriptors), 1) * self.idf
        total = weighted.sum()
        return weighted / total if total > 0 else weighted


def similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """L1 score 1 − ½‖a − b‖₁ of (V,) vector a against (V,) or (N, V) b (Gálvez-López & Tardós 2012, eq. 2)."""
    return np.asarray(1.0 - 0.5 * np.abs(b - a).sum(axis=-1))
