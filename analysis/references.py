"""The published sources of the methods the paper's text names, so an author can cite them.

Each entry is found by a phrase the methods text uses when (and only when) it applies that
method; :func:`cited` lists the entries of a text in the order the text first names them.
"""

from __future__ import annotations

#: (phrases that name the method in the methods text, the reference)
REFERENCES: tuple[tuple[tuple[str, ...], str], ...] = (
    (("Li et al. 2020",),
     "Li, Z., Bampis, C. G., Krasula, L., Janowski, L., Katsavounidis, I. (2020). A simple "
     "model for subject behavior in subjective experiments. IS&T Electronic Imaging, Human "
     "Vision and Electronic Imaging."),
    (("ITU-T P.913",),
     "ITU-T Recommendation P.913: Methods for the subjective assessment of video quality, "
     "audio quality and audiovisual quality of Internet video and distribution quality "
     "television in any environment."),
    (("ITU-R BT.500",),
     "ITU-R Recommendation BT.500: Methodologies for the subjective assessment of the quality "
     "of television images."),
    (("Grubbs",),
     "Grubbs, F. E. (1969). Procedures for detecting outlying observations in samples. "
     "Technometrics 11(1), 1-21."),
    (("ITU-T P.910",),
     "ITU-T Recommendation P.910: Subjective video quality assessment methods for multimedia "
     "applications."),
    (("Kish's effective",),
     "Kish, L. (1965). Survey Sampling. Wiley, New York."),
    (("ICC(2,k)",),
     "Shrout, P. E., Fleiss, J. L. (1979). Intraclass correlations: uses in assessing rater "
     "reliability. Psychological Bulletin 86(2), 420-428."),
    (("Spearman-Brown",),
     "Spearman, C. (1910). Correlation calculated from faulty data. British Journal of "
     "Psychology 3(3), 271-295. Brown, W. (1910). Some experimental results in the "
     "correlation of mental abilities. British Journal of Psychology 3(3), 296-322."),
    (("ITU-T P.1401",),
     "ITU-T Recommendation P.1401: Methods, metrics and procedures for statistical "
     "evaluation, qualification and comparison of objective quality prediction models."),
    (("5-parameter logistic",),
     "Sheikh, H. R., Sabir, M. F., Bovik, A. C. (2006). A statistical evaluation of recent "
     "full reference image quality assessment algorithms. IEEE Transactions on Image "
     "Processing 15(11), 3440-3451."),
    (("CGVQM", "paired bootstrap"),
     "Jindal, A., et al. (2025). CGVQM+D: Computer Graphics Video Quality Metric and "
     "Dataset. Computer Graphics Forum."),
    (("Williams' t",),
     "Williams, E. J. (1959). The comparison of regression variables. Journal of the Royal "
     "Statistical Society, Series B 21(2), 396-399."),
    (("Steiger's Z",),
     "Steiger, J. H. (1980). Tests for comparing elements of a correlation matrix. "
     "Psychological Bulletin 87(2), 245-251."),
)


def cited(text: str) -> list[str]:
    """The references of the methods ``text`` names, in the order it first names them."""
    found = []
    for phrases, reference in REFERENCES:
        at = [text.find(p) for p in phrases if p in text]
        if at:
            found.append((min(at), reference))
    return [reference for _, reference in sorted(found)]
