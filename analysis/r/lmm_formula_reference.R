# lme4 + car (+ lmerTest) reference values for a model given by its formula, for tests/analysis.
#
# Usage:
#   Rscript analysis/r/lmm_formula_reference.R export NAME OUT.csv
#       writes lme4's data set NAME (sleepstudy, Penicillin, Pastes, Dyestuff) as CSV
#   Rscript analysis/r/lmm_formula_reference.R data=DATA.csv formula=FORMULA reml=0|1 \
#       factors=a,b out=OUT.csv [thetas=THETAS.csv] [contrasts=L.csv] [start=START.csv]
#     factors    columns read as factors (grouping factors and categorical predictors)
#     thetas     one theta per row (no header): devFunOnly criterion at each ("dev_at")
#     contrasts  a header row of coefficient names plus "term"; each row one row of a hypothesis
#                matrix L; lmerTest::contest(..., ddf = "Satterthwaite") per term ("contest")
#     start      one theta (no header): the fit takes the better of lme4's start and this one
#                ("dev_cold" / "dev_warm": the criterion at the optimum from each, unpolished)
#   OUT.csv rows key,name,value: fixef, se, vcov, theta, sigma, loglik, deviance, sd and cor
#     (named group|coefficient), chisq and chisq_df (car::Anova type 2), singular, dev_at,
#     dev_cold, dev_warm, satt_df and satt_t (lmerTest's summary), contest_F / contest_numdf /
#     contest_dendf.
# The fit uses nloptwrap's BOBYQA with tolerances far tighter than lme4's defaults, then Newton
# steps on lme4's own devfun (numDeriv's Richardson derivatives, parameters on their bound left
# there; a step kept if the criterion does not rise beyond its rounding error): on flat
# likelihoods BOBYQA alone leaves theta uncertain in the 6th digit. Everything reported is lme4's
# at the polished theta (mkMerMod, as lmer itself builds its result).
suppressPackageStartupMessages({library(lme4); library(car)})
args <- commandArgs(trailingOnly = TRUE)
if (length(args) >= 1 && args[1] == "export") {
  d <- get(args[2], envir = asNamespace("lme4"))
  write.csv(d, args[3], row.names = FALSE)
  quit(status = 0)
}
kv <- setNames(sub("^[^=]*=", "", args), sub("=.*$", "", args))
need <- c("data", "formula", "reml", "out")
if (!all(need %in% names(kv))) stop("usage: see the header of lmm_formula_reference.R")
factors <- if (is.na(kv["factors"]) || kv[["factors"]] == "") character(0) else
  strsplit(kv[["factors"]], ",")[[1]]
cc <- setNames(rep("character", length(factors)), factors)
d <- read.csv(kv[["data"]], colClasses = cc, check.names = FALSE)
for (f in factors) d[[f]] <- factor(d[[f]])
form <- as.formula(kv[["formula"]])
reml <- kv[["reml"]] == "1"
have_lmertest <- requireNamespace("lmerTest", quietly = TRUE)
ctrl <- lmerControl(optimizer = "nloptwrap", calc.derivs = FALSE,
                    optCtrl = list(xtol_abs = 1e-10, ftol_abs = 1e-12, ftol_rel = 0,
                                   xtol_rel = 0, maxeval = 100000),
                    check.conv.singular = "ignore")
fitter <- if (have_lmertest) lmerTest::lmer else lme4::lmer
fit <- fitter(form, data = d, REML = reml, control = ctrl)
starts <- NULL
if (!is.na(kv["start"])) {
  st <- as.numeric(read.csv(kv[["start"]], header = FALSE)[1, ])
  hot <- fitter(form, data = d, REML = reml, control = ctrl, start = list(theta = st))
  starts <- c(cold = deviance(fit, REML = reml), warm = deviance(hot, REML = reml))
  if (deviance(hot, REML = reml) < deviance(fit, REML = reml)) fit <- hot
}
polish <- function(fit) {
  lf <- lFormula(form, data = d, REML = reml)
  devfun <- do.call(mkLmerDevfun, lf)
  theta <- getME(fit, "theta")
  lower <- getME(fit, "lower")
  free <- which(!(lower == 0 & theta < 1e-6))
  if (length(free)) for (k in 1:4) {
    f_free <- function(x) { th <- theta; th[free] <- x; devfun(th) }
    f0 <- f_free(theta[free])
    g <- numDeriv::grad(f_free, theta[free])
    H <- numDeriv::hessian(f_free, theta[free])
    if (any(eigen(H, symmetric = TRUE, only.values = TRUE)$values <= 0)) break
    step <- solve(H, g)
    new <- theta
    new[free] <- pmax(theta[free] - step, lower[free])
    if (devfun(new) > f0 + 1e-10 * abs(f0)) break
    theta <- new
    if (max(abs(step)) < 1e-10 * max(1, abs(theta))) break
  }
  opt <- list(par = theta, fval = devfun(theta), conv = 0, message = "polished")
  out <- mkMerMod(environment(devfun), opt, lf$reTrms, fr = lf$fr, mc = fit@call)
  if (have_lmertest) lmerTest::as_lmerModLmerTest(out) else out
}
fit <- polish(fit)
out <- list()
add <- function(key, name, value) out[[length(out) + 1]] <<- data.frame(
  key = key, name = name, value = sprintf("%.17g", value))
fe <- fixef(fit)
add("fixef", names(fe), fe)
V <- as.matrix(vcov(fit))
add("se", names(fe), sqrt(diag(V)))
add("vcov", paste(rep(names(fe), each = length(fe)), rep(names(fe), length(fe)), sep = "|"),
    as.vector(t(V)))
add("theta", seq_along(getME(fit, "theta")), getME(fit, "theta"))
add("sigma", "", sigma(fit))
add("loglik", "", as.numeric(logLik(fit)))
add("deviance", "", if (reml) REMLcrit(fit) else deviance(fit))
vc <- as.data.frame(VarCorr(fit))
sds <- vc[vc$grp != "Residual" & is.na(vc$var2), ]
add("sd", paste(sds$grp, sds$var1, sep = "|"), sds$sdcor)
cors <- vc[!is.na(vc$var2), ]
if (nrow(cors)) add("cor", paste(cors$grp, paste(cors$var1, cors$var2, sep = ","), sep = "|"),
                    cors$sdcor)
if (length(fe) > 1) {
  a <- Anova(fit, type = 2)
  add("chisq", rownames(a), a$Chisq)
  add("chisq_df", rownames(a), a$Df)
}
add("singular", "", as.numeric(isSingular(fit)))
if (!is.na(kv["thetas"])) {
  devfun <- lme4::lmer(form, data = d, REML = reml, devFunOnly = TRUE)
  thetas <- as.matrix(read.csv(kv[["thetas"]], header = FALSE))
  for (k in seq_len(nrow(thetas))) add("dev_at", k, devfun(thetas[k, ]))
}
if (!is.null(starts)) {
  add("dev_cold", "", starts[["cold"]])
  add("dev_warm", "", starts[["warm"]])
}
if (have_lmertest) {
  s <- summary(fit, ddf = "Satterthwaite")$coefficients
  add("satt_df", rownames(s), s[, "df"])
  add("satt_t", rownames(s), s[, "t value"])
  if (!is.na(kv["contrasts"])) {
    L <- read.csv(kv[["contrasts"]], check.names = FALSE)
    for (term in unique(L$term)) {
      Lt <- as.matrix(L[L$term == term, names(fe), drop = FALSE])
      ct <- lmerTest::contest(fit, Lt, ddf = "Satterthwaite", joint = TRUE)
      add("contest_F", term, ct[["F value"]])
      add("contest_numdf", term, ct[["NumDF"]])
      add("contest_dendf", term, ct[["DenDF"]])
    }
  }
}
write.csv(do.call(rbind, out), kv[["out"]], row.names = FALSE, quote = TRUE)
