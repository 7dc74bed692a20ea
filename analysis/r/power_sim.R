# Power by simulation in R, the loop simr's powerSim runs: lme4's simulate() on the planned
# layout (new participants' random effects drawn from the fitted model, allow.new.levels), refit()
# of each simulated response, car::Anova(type = 2) and a count of p < alpha per term. Reference
# for analysis.power (tests/analysis/test_power_r.py) and bench/analysis_power_vs_simr.py.
#
# Rscript power_sim.R data=PILOT.csv formula=F beta=B.csv layouts=L1.csv,L2.csv terms=a,b
#                     nsim=N seed=S alpha=A out=OUT.csv
# beta: the fixed effects to simulate with (one column, R's order; the fitted ones scaled).
# OUT: one row per layout and term: layout, term, hits, nsim, seconds (simulate + refits + tests).
suppressPackageStartupMessages({library(lme4); library(car)})
kv <- commandArgs(trailingOnly = TRUE)
opt <- setNames(sub("^[^=]*=", "", kv), sub("=.*$", "", kv))
f <- as.formula(opt[["formula"]])
ctrl <- lmerControl(calc.derivs = FALSE)
d <- read.csv(opt[["data"]])
d$participant <- factor(d$participant)
fit <- lmer(f, d, REML = FALSE, control = ctrl)
beta <- read.csv(opt[["beta"]], header = FALSE)[[1]]
names(beta) <- names(fixef(fit))
params <- list(beta = beta, theta = getME(fit, "theta"), sigma = sigma(fit))
terms <- strsplit(opt[["terms"]], ",")[[1]]
nsim <- as.integer(opt[["nsim"]])
alpha <- as.numeric(opt[["alpha"]])
set.seed(as.integer(opt[["seed"]]))
rows <- list()
for (layout in strsplit(opt[["layouts"]], ",")[[1]]) {
  new <- read.csv(layout)
  new$participant <- factor(new$participant)
  resp <- all.vars(f)[1]
  t0 <- proc.time()[["elapsed"]]
  ys <- simulate(fit, nsim = nsim, newdata = new, allow.new.levels = TRUE,
                 newparams = params, use.u = FALSE)
  new[[resp]] <- ys[[1]]
  m <- suppressMessages(lmer(f, new, REML = FALSE, control = ctrl,
                             start = list(theta = getME(fit, "theta"))))
  hits <- setNames(integer(length(terms)), terms)
  for (i in seq_len(nsim)) {
    mi <- if (i == 1) m else suppressMessages(refit(m, ys[[i]]))
    p <- Anova(mi, type = 2)[terms, "Pr(>Chisq)"]
    hits <- hits + (p < alpha)
  }
  secs <- proc.time()[["elapsed"]] - t0
  rows[[layout]] <- data.frame(layout = basename(layout), term = terms, hits = as.integer(hits),
                               nsim = nsim, seconds = secs)
}
write.csv(do.call(rbind, rows), opt[["out"]], row.names = FALSE)
