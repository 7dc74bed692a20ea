# lme4's bootMer on a data set, for bench/analysis_bootstrap_vs_bootmer.py.
#
# Usage: Rscript analysis/r/bootmer.R DATA.csv NSIM NCPUS SEED OUT.csv FORMULA
#   DATA.csv  participant, stimulus_id, gloss, depth, y (the frame analysis.lmm.fit fits)
#   OUT.csv   one row per run: fixed effects, random-effect SDs, sigma, Type II chi-squares
#   FORMULA   an lme4 formula, fitted by ML
# Prints "seconds_per_refit <s>" (bootMer alone, wall clock), timed after the first fit.
suppressPackageStartupMessages({library(lme4); library(car)})
args <- commandArgs(trailingOnly = TRUE)
d <- read.csv(args[1], colClasses = c(participant = "character", stimulus_id = "character"))
nsim <- as.integer(args[2]); ncpus <- as.integer(args[3]); set.seed(as.integer(args[4]))
fit <- lmer(as.formula(args[6]), data = d, REML = FALSE)
stat <- function(m) {
  vc <- as.data.frame(VarCorr(m))
  c(fixef(m), vc$sdcor[vc$grp != "Residual" & is.na(vc$var2)], sigma(m),
    Anova(m, type = 2)$Chisq)
}
t <- system.time(b <- bootMer(fit, stat, nsim = nsim, type = "parametric", use.u = FALSE,
                              parallel = if (ncpus > 1) "multicore" else "no", ncpus = ncpus))
cat("seconds_per_refit", t[["elapsed"]] / nsim, "\n")
cat("fixef", fixef(fit), "\n")
write.csv(b$t, args[5], row.names = FALSE)
