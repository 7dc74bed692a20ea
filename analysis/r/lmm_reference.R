# Reference values from R's lme4 + car for analysis/lmm.py and analysis/typeii.py.
#
# Usage: Rscript analysis/r/lmm_reference.R DATA.csv THETAS.csv START.csv OUT.csv
#   DATA.csv   columns participant, gloss, depth, y (standardised predictors, as analysis.lmm)
#   THETAS.csv one theta per row (6 columns, lme4's order), for the deviance at fixed theta
#   START.csv  one theta (a warm start, e.g. analysis.lmm.moment_start's); the fit takes the
#              better of lme4's default start and this one, as analysis.lmm.fit_lmm does
#   OUT.csv    key,name,value rows: fixef, se, vcov, theta, sigma, loglik, deviance, sd, cor,
#              chisq (car::Anova type 2), singular, dev_at (devfun at each given theta),
#              dev_cold / dev_warm (the optimum from each start)
# The fit uses nloptwrap's BOBYQA with tolerances far tighter than lme4's defaults (which stop up
# to 6e-4 from the optimum), so two implementations can be compared to 1e-5.
suppressPackageStartupMessages({library(lme4); library(car)})
args <- commandArgs(trailingOnly = TRUE)
if (length(args) != 4) {
  stop("usage: Rscript lmm_reference.R DATA.csv THETAS.csv START.csv OUT.csv")
}
d <- read.csv(args[1], colClasses = c(participant = "character"))
thetas <- as.matrix(read.csv(args[2], header = FALSE))
warm <- as.numeric(read.csv(args[3], header = FALSE)[1, ])
form <- y ~ gloss * depth + (1 + gloss + depth | participant)
ctrl <- lmerControl(optimizer = "nloptwrap", calc.derivs = FALSE,
                    optCtrl = list(xtol_abs = 1e-10, ftol_abs = 1e-12, ftol_rel = 0,
                                   xtol_rel = 0, maxeval = 100000),
                    check.conv.singular = "ignore")
cold <- lmer(form, data = d, REML = FALSE, control = ctrl)
hot <- lmer(form, data = d, REML = FALSE, control = ctrl, start = list(theta = warm))
fit <- if (deviance(hot) < deviance(cold)) hot else cold
devfun <- lmer(form, data = d, REML = FALSE, devFunOnly = TRUE)
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
add("deviance", "", deviance(fit))
vc <- as.data.frame(VarCorr(fit))
sds <- vc[vc$grp == "participant" & is.na(vc$var2), ]
add("sd", sds$var1, sds$sdcor)
cors <- vc[vc$grp == "participant" & !is.na(vc$var2), ]
add("cor", paste(cors$var1, cors$var2, sep = ","), cors$sdcor)
a <- Anova(fit, type = 2)
add("chisq", rownames(a), a$Chisq)
add("singular", "", as.numeric(isSingular(fit)))
for (k in seq_len(nrow(thetas))) add("dev_at", k, devfun(thetas[k, ]))
add("dev_cold", "", deviance(cold))
add("dev_warm", "", deviance(hot))
write.csv(do.call(rbind, out), args[4], row.names = FALSE, quote = TRUE)
